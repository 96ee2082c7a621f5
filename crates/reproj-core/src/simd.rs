//! The run-time dispatch of the row loops of `ours` and `timewarp` by instruction set:
//! [`simd_dispatch`] for functions, [`simd_method`] for methods of `ours`' `Resolve`. Not a stage
//! of the paper (seeds/000 §3): these only let the compiler use 256- and 512-bit vectors for the same IEEE
//! arithmetic, without FMA contraction, so that the output bytes do not depend on the processor
//! (the fused multiply-adds written out, in `camera::centre_quotient`, give the division's bytes).
//! [`set_simd_limit`] (or the environment variable `REPROJ_SIMD`) caps the instruction set, so
//! that a test can compare the tiers' bytes on one processor and a benchmark can time them
//! against each other.

use std::sync::atomic::{AtomicU8, Ordering};

/// The instruction sets the row loops of `ours` and `timewarp` are compiled for, lowest first.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Simd {
    /// The target's baseline (SSE2 on x86-64).
    Baseline = 0,
    /// AVX2 with FMA (256-bit vectors, gathers).
    Avx2 = 1,
    /// The AVX-512 of x86-64-v4: F, BW, CD, DQ and VL (512-bit vectors, masked loads and stores).
    Avx512 = 2,
}

impl std::str::FromStr for Simd {
    type Err = String;

    /// `baseline`, `avx2` or `avx512` (as `REPROJ_SIMD` names them).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "baseline" => Ok(Simd::Baseline),
            "avx2" => Ok(Simd::Avx2),
            "avx512" => Ok(Simd::Avx512),
            _ => Err(format!("{s:?} is not baseline, avx2 or avx512")),
        }
    }
}

/// The highest tier [`simd_tier`] may return (a [`Simd`] as `u8`), or [`UNSET`].
static LIMIT: AtomicU8 = AtomicU8::new(UNSET);

/// [`LIMIT`] before the first row: `REPROJ_SIMD` is read then.
const UNSET: u8 = u8::MAX;

/// Caps the instruction set of the row loops of `ours` and `timewarp` at `limit` for the whole
/// process from the next row on. The default is `REPROJ_SIMD` (`baseline`, `avx2` or `avx512`,
/// read once) where that is set, else [`Simd::Avx512`], i.e. the best the processor has. Every
/// tier gives the same bytes; this is for tests that check that, and for timing one tier against
/// another.
pub fn set_simd_limit(limit: Simd) {
    LIMIT.store(limit as u8, Ordering::Relaxed);
}

/// The tier the row loops use now: the best the processor has, at most [`set_simd_limit`]'s.
#[inline]
pub fn simd_tier() -> Simd {
    let mut limit = LIMIT.load(Ordering::Relaxed);
    if limit == UNSET {
        limit = limit_from_env();
    }
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::is_x86_feature_detected as has;
        if limit >= Simd::Avx512 as u8
            && has!("avx512f")
            && has!("avx512bw")
            && has!("avx512cd")
            && has!("avx512dq")
            && has!("avx512vl")
        {
            return Simd::Avx512;
        }
        if limit >= Simd::Avx2 as u8 && has!("avx2") && has!("fma") {
            return Simd::Avx2;
        }
    }
    let _ = limit;
    Simd::Baseline
}

/// The first [`simd_tier`]: [`LIMIT`] from `REPROJ_SIMD` (any other value caps nothing).
#[cold]
fn limit_from_env() -> u8 {
    let limit = std::env::var("REPROJ_SIMD")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(Simd::Avx512) as u8;
    // A set_simd_limit that came first wins over the environment.
    match LIMIT.compare_exchange(UNSET, limit, Ordering::Relaxed, Ordering::Relaxed) {
        Ok(_) => limit,
        Err(set) => set,
    }
}

/// Defines `$name`, which runs the `#[inline(always)]` function `$imp` compiled for AVX-512 (as
/// `$avx512`) or AVX2 (as `$avx2`) where the processor has it ([`simd_tier`]) and for the baseline
/// otherwise. The body is written once; the wider builds let the compiler use wider vectors (and
/// masks) for its row loops. No build contracts multiplies and adds into FMA (Rust never does), so
/// all give the same bytes. Both wider builds have FMA instructions (AVX-512 F implies them), for
/// the `mul_add`s written out (`camera::centre_quotient`), which give the same bytes as the
/// baseline's division.
///
/// With `$imp(gathers, …)`, `$imp` also takes a `Gathers` (`ours/search.rs`) first: the
/// portable loops for the baseline, the AVX2 gather instructions for both wider builds.
macro_rules! simd_dispatch {
    (@gen [$($doc:tt)*] $name:ident $avx2:ident $avx512:ident $imp:ident [$($base:tt)*] [$($wide:tt)*] $($arg:ident: $ty:ty),*) => {
        $($doc)*
        #[inline]
        fn $name($($arg: $ty),*) {
            #[cfg(target_arch = "x86_64")]
            match $crate::simd::simd_tier() {
                // SAFETY: the processor supports AVX-512 F/BW/CD/DQ/VL (checked by simd_tier).
                $crate::simd::Simd::Avx512 => return unsafe { $avx512($($arg),*) },
                // SAFETY: the processor supports AVX2 and FMA (checked by simd_tier).
                $crate::simd::Simd::Avx2 => return unsafe { $avx2($($arg),*) },
                $crate::simd::Simd::Baseline => {}
            }
            $imp($($base)* $($arg),*)
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2,fma")]
        fn $avx2($($arg: $ty),*) {
            $imp($($wide)* $($arg),*)
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx512f,avx512bw,avx512cd,avx512dq,avx512vl")]
        fn $avx512($($arg: $ty),*) {
            $imp($($wide)* $($arg),*)
        }
    };
    ($(#[$doc:meta])* fn $name:ident / $avx2:ident, $avx512:ident => $imp:ident(gathers, $($arg:ident: $ty:ty),* $(,)?)) => {
        simd_dispatch!(@gen [$(#[$doc])*] $name $avx2 $avx512 $imp
            [super::search::Portable,] [super::search::x86::Avx2::new(),] $($arg: $ty),*);
    };
    ($(#[$doc:meta])* fn $name:ident / $avx2:ident, $avx512:ident => $imp:ident($($arg:ident: $ty:ty),* $(,)?)) => {
        simd_dispatch!(@gen [$(#[$doc])*] $name $avx2 $avx512 $imp [] [] $($arg: $ty),*);
    };
}

/// [`simd_dispatch`] for a method of `ours`' `Resolve`: `$name` runs the
/// `#[inline(always)]` method `$imp` compiled for AVX-512 (as `$avx512`) or AVX2 (as `$avx2`)
/// where the processor has it; `$imp(&self, gathers, …)` as in [`simd_dispatch`].
macro_rules! simd_method {
    (@gen [$($doc:tt)*] $vis:vis $name:ident $avx2:ident $avx512:ident $imp:ident [$($base:tt)*] [$($wide:tt)*] $($arg:ident: $ty:ty),*) => {
        $($doc)*
        #[inline(never)]
        $vis fn $name(&self, $($arg: $ty),*) {
            #[cfg(target_arch = "x86_64")]
            match $crate::simd::simd_tier() {
                // SAFETY: the processor supports AVX-512 F/BW/CD/DQ/VL (checked by simd_tier).
                $crate::simd::Simd::Avx512 => return unsafe { self.$avx512($($arg),*) },
                // SAFETY: the processor supports AVX2 and FMA (checked by simd_tier).
                $crate::simd::Simd::Avx2 => return unsafe { self.$avx2($($arg),*) },
                $crate::simd::Simd::Baseline => {}
            }
            self.$imp($($base)* $($arg),*)
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2,fma")]
        fn $avx2(&self, $($arg: $ty),*) {
            self.$imp($($wide)* $($arg),*)
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx512f,avx512bw,avx512cd,avx512dq,avx512vl")]
        fn $avx512(&self, $($arg: $ty),*) {
            self.$imp($($wide)* $($arg),*)
        }
    };
    ($(#[$doc:meta])* $vis:vis fn $name:ident / $avx2:ident, $avx512:ident => $imp:ident(&self, gathers, $($arg:ident: $ty:ty),* $(,)?)) => {
        simd_method!(@gen [$(#[$doc])*] $vis $name $avx2 $avx512 $imp
            [super::search::Portable,] [super::search::x86::Avx2::new(),] $($arg: $ty),*);
    };
    ($(#[$doc:meta])* $vis:vis fn $name:ident / $avx2:ident, $avx512:ident => $imp:ident(&self, $($arg:ident: $ty:ty),* $(,)?)) => {
        simd_method!(@gen [$(#[$doc])*] $vis $name $avx2 $avx512 $imp [] [] $($arg: $ty),*);
    };
}

pub(crate) use simd_dispatch;
pub(crate) use simd_method;

/// Asks the processor to bring the cache line holding `p` into its L2 cache (x86-64's
/// `prefetcht1`; nothing elsewhere). A hint only: it loads nothing the program sees and cannot
/// fault, whatever the address, so the bytes never depend on it.
#[inline(always)]
pub(crate) fn prefetch<T>(p: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: `prefetcht1` is SSE, which every x86-64 processor has; it never faults and has no
    // effect visible to the program.
    unsafe {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T1};
        _mm_prefetch::<_MM_HINT_T1>(p.cast());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}
