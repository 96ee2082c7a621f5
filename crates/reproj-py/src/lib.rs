//! Bindings (being written).
