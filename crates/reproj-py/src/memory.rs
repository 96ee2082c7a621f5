//! A call's memory, reserved before the call starts.
//!
//! An allocation that fails inside Rust aborts the process (a message and a backtrace on
//! stderr, no exception), and the sizes the bindings accept reach 16384×16384, far beyond most
//! machines. So every binding that allocates in proportion to its sizes first asks the system
//! for its bound of `reproj_core::memory` (or reproj-scene's) at once, without touching the
//! pages, and hands it back: when that fails it raises `OutOfMemoryError` naming the call and
//! the bytes, and nothing else was allocated. A reservation that succeeds does not promise that
//! the call's own allocations will (another thread may take the memory meanwhile, and with
//! overcommit the kernel may grant what it cannot back), but a request too large for the
//! machine is refused before it starts.

use pyo3::prelude::*;

use crate::errors::out_of_memory;

/// `bytes` in the largest binary unit that keeps it at least 1, with one decimal.
fn human(bytes: u64) -> String {
    let units = ["B", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"];
    let mut v = bytes as f64;
    let mut k = 0;
    while v >= 1024.0 && k + 1 < units.len() {
        v /= 1024.0;
        k += 1;
    }
    if k == 0 {
        format!("{bytes} B")
    } else {
        format!("{v:.1} {}", units[k])
    }
}

/// Whether `bytes` could be allocated now: reserved (address space, not pages) and released.
fn can_allocate(bytes: u64) -> bool {
    usize::try_from(bytes).is_ok_and(|n| Vec::<u8>::new().try_reserve_exact(n).is_ok())
}

/// Checks that `bytes` can be allocated before `what` (a call and its sizes) allocates them;
/// `OutOfMemoryError` otherwise.
pub(crate) fn reserve(bytes: u64, what: impl FnOnce() -> String) -> PyResult<()> {
    if can_allocate(bytes) {
        return Ok(());
    }
    Err(out_of_memory(format!(
        "{}: needs about {} of memory, which this machine could not allocate; ask for fewer \
         pixels",
        what(),
        human(bytes)
    )))
}
