//! The WGSL sources, composed from `shaders/*.wgsl` and the shared code in `shaders/shared/`.
//!
//! WGSL has no `#include`, so a module is the shared files followed by its own file, in the order
//! of [`SHARED`]. Everything is embedded at compile time; `tests/naga.rs` parses and validates
//! every composed module with naga.

/// The shared files, in the order they are prepended: bindings and types, camera maths, shadows.
pub const SHARED: [(&str, &str); 3] = [
    (
        "shared/bindings.wgsl",
        include_str!("../shaders/shared/bindings.wgsl"),
    ),
    (
        "shared/camera.wgsl",
        include_str!("../shaders/shared/camera.wgsl"),
    ),
    (
        "shared/shadow.wgsl",
        include_str!("../shaders/shared/shadow.wgsl"),
    ),
];

/// Pass 1's shared part (scene flow of one source pixel), prepended to both splat variants.
pub const SCENE_FLOW: (&str, &str) = (
    "shared/scene_flow.wgsl",
    include_str!("../shaders/shared/scene_flow.wgsl"),
);

/// Which module.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Module {
    /// Pass 1 with 64-bit atomics (`splat64.wgsl`, entry point `splat_main`).
    Splat64,
    /// Pass 1 with 32-bit atomics in two dispatches (`splat32.wgsl`, `depth_pass`, `index_pass`).
    Splat32,
    /// Pass 2 (`resolve.wgsl`, entry points `aux_grid` and `resolve`).
    Resolve,
}

impl Module {
    /// Every module.
    pub const ALL: [Module; 3] = [Module::Splat64, Module::Splat32, Module::Resolve];

    /// The module's own file and its text.
    pub fn file(self) -> (&'static str, &'static str) {
        match self {
            Module::Splat64 => ("splat64.wgsl", include_str!("../shaders/splat64.wgsl")),
            Module::Splat32 => ("splat32.wgsl", include_str!("../shaders/splat32.wgsl")),
            Module::Resolve => ("resolve.wgsl", include_str!("../shaders/resolve.wgsl")),
        }
    }

    /// The entry points the host uses.
    pub fn entry_points(self) -> &'static [&'static str] {
        match self {
            Module::Splat64 => &["splat_main"],
            Module::Splat32 => &["depth_pass", "index_pass"],
            Module::Resolve => &["aux_grid", "resolve"],
        }
    }

    /// Whether the module needs 64-bit integers and 64-bit atomic min/max.
    pub fn needs_int64(self) -> bool {
        self == Module::Splat64
    }

    /// The composed WGSL source.
    pub fn source(self) -> String {
        let mut parts: Vec<(&str, &str)> = SHARED.to_vec();
        if self != Module::Resolve {
            parts.push(SCENE_FLOW);
        }
        parts.push(self.file());
        let mut s = String::new();
        for (name, text) in parts {
            s.push_str("// ---- ");
            s.push_str(name);
            s.push_str(" ----\n");
            s.push_str(text);
            s.push('\n');
        }
        s
    }
}
