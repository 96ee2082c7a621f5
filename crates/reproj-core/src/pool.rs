//! Dedicated rayon pools, for work that must not share the global pool with the display path.
//!
//! A client prepares the next server-frame pair ([`crate::prepare_pair`]) while it keeps
//! displaying frames of the current one. On rayon's global pool the preparation's tasks would
//! queue with the display frame's and delay it; on a pool of its own the operating system shares
//! the cores between the two instead, and the display thread's pool stays free.

use std::sync::{Arc, Mutex, PoisonError};

use rayon::{ThreadPool, ThreadPoolBuildError, ThreadPoolBuilder};

/// The pools made so far, by thread count: a pool's threads live as long as the process, so a
/// caller that prepares every pair reuses them instead of starting threads per call.
static POOLS: Mutex<Vec<(usize, Arc<ThreadPool>)>> = Mutex::new(Vec::new());

/// Runs `f` on the dedicated pool of `threads` threads (made on first use, then kept), and waits
/// for it. The rayon calls inside `f` run on that pool.
///
/// # Errors
/// When the pool's threads cannot be started.
pub fn install<T: Send>(
    threads: usize,
    f: impl FnOnce() -> T + Send,
) -> Result<T, ThreadPoolBuildError> {
    let pool = {
        // A panic while the lock was held left the list whole (it only pushes), so a poisoned
        // lock is still usable.
        let mut pools = POOLS.lock().unwrap_or_else(PoisonError::into_inner);
        match pools.iter().find(|(n, _)| *n == threads) {
            Some((_, p)) => Arc::clone(p),
            None => {
                let p = Arc::new(
                    ThreadPoolBuilder::new()
                        .num_threads(threads)
                        .thread_name(move |i| format!("reproj-pool{threads}-{i}"))
                        .build()?,
                );
                pools.push((threads, Arc::clone(&p)));
                p
            }
        }
    };
    // Outside the lock: callers on other threads may use other pools (or this one) meanwhile.
    Ok(pool.install(f))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_on_a_kept_pool_of_that_many_threads() {
        let first = install(3, rayon::current_num_threads).unwrap();
        assert_eq!(first, 3);
        let name = install(3, || std::thread::current().name().map(str::to_owned)).unwrap();
        assert!(name.is_some_and(|n| n.starts_with("reproj-pool3-")));
        let kept = POOLS
            .lock()
            .unwrap()
            .iter()
            .filter(|(n, _)| *n == 3)
            .count();
        assert_eq!(kept, 1);
    }
}
