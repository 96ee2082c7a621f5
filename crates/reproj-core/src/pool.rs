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

/// The operating system's thread ids (Linux `gettid`) of the threads of rayon's global pool,
/// where `reproject` runs a client frame, in pool order (the pool is started if it was not).
/// Empty on other systems.
///
/// A real-time client gives these threads, and its display thread, a real-time scheduling policy
/// while it shows frames (`splitrender.client.realtime`): Linux's fair scheduler can run a
/// lower-priority thread (even one of policy `SCHED_IDLE`) for up to a tick before a runnable
/// display thread, which takes a display frame past its deadline.
pub fn global_thread_ids() -> Vec<i64> {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: gettid has no preconditions and cannot fail.
        rayon::broadcast(|_| i64::from(unsafe { libc::gettid() }))
    }
    #[cfg(not(target_os = "linux"))]
    {
        Vec::new()
    }
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

    #[cfg(target_os = "linux")]
    #[test]
    fn global_thread_ids_are_the_pool_threads() {
        let ids = global_thread_ids();
        assert_eq!(ids.len(), rayon::current_num_threads());
        // Distinct, and none of them the calling thread (which is not in the pool).
        let mut sorted = ids.clone();
        sorted.sort_unstable();
        sorted.dedup();
        assert_eq!(sorted.len(), ids.len());
        // SAFETY: as in `global_thread_ids`.
        let me = i64::from(unsafe { libc::gettid() });
        assert!(!ids.contains(&me));
        // Each is a thread of this process.
        for id in ids {
            assert!(std::path::Path::new(&format!("/proc/self/task/{id}")).exists());
        }
    }
}
