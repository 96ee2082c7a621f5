//! A small analytic scene for tests, benchmarks and the example. (Being written.)
