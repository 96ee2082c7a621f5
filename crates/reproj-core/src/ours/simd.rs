//! The AVX2 dispatch of the row loops of `ours`: [`avx2_dispatch`] for functions,
//! [`avx2_method`] for methods of [`super::Resolve`]. Not a stage of the paper (seeds/000 §3):
//! these only let the compiler use 256-bit vectors for the same IEEE arithmetic, without FMA
//! contraction, so that the output bytes do not depend on the processor.

/// Defines `$name`, which runs the `#[inline(always)]` function `$imp` compiled for AVX2 (as
/// `$avx`) where the processor has it and for the baseline otherwise. The body is written once;
/// the AVX2 build lets the compiler use 256-bit vectors for its row loops. Neither build contracts
/// multiplies and adds into FMA, so both give the same bytes.
macro_rules! avx2_dispatch {
    ($(#[$doc:meta])* fn $name:ident / $avx:ident => $imp:ident($($arg:ident: $ty:ty),* $(,)?)) => {
        $(#[$doc])*
        #[inline]
        fn $name($($arg: $ty),*) {
            #[cfg(target_arch = "x86_64")]
            {
                if std::arch::is_x86_feature_detected!("avx2") {
                    // SAFETY: the processor supports AVX2 (checked just above).
                    unsafe { $avx($($arg),*) };
                    return;
                }
            }
            $imp($($arg),*)
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2")]
        fn $avx($($arg: $ty),*) {
            $imp($($arg),*)
        }
    };
}

/// [`avx2_dispatch`] for a method of [`Resolve`](super::Resolve): `$name` runs the `#[inline(always)]` method
/// `$imp` compiled for AVX2 (as `$avx`) where the processor has it.
macro_rules! avx2_method {
    ($(#[$doc:meta])* $vis:vis fn $name:ident / $avx:ident => $imp:ident(&self, $($arg:ident: $ty:ty),* $(,)?)) => {
        $(#[$doc])*
        #[inline(never)]
        $vis fn $name(&self, $($arg: $ty),*) {
            #[cfg(target_arch = "x86_64")]
            {
                if std::arch::is_x86_feature_detected!("avx2") {
                    // SAFETY: the processor supports AVX2 (checked just above).
                    unsafe { self.$avx($($arg),*) };
                    return;
                }
            }
            self.$imp($($arg),*)
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2")]
        fn $avx(&self, $($arg: $ty),*) {
            self.$imp($($arg),*)
        }
    };
}

pub(super) use avx2_dispatch;
pub(super) use avx2_method;
