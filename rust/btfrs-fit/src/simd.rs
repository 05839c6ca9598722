//! Loops compiled for wider vectors and chosen at run time.
//!
//! The wheel is built for the x86-64 baseline (SSE2), so a loop that gains from AVX2 or
//! AVX-512 is compiled again with those features enabled and picked by a CPU check on each
//! call (a cached flag). [`by_cpu!`] writes the pair of functions once: the public one with the
//! baseline body, and per feature a `#[target_feature]` copy with its own body. The bodies
//! may differ, e.g. in lane counts sized to the vector width.
//!
//! The `multiversion` crate does the same for one body compiled several times. Here the forms
//! differ (48, 24 or 12 lanes; 8 texels or 1), which is why this is a small macro of its own.

/// `fn name(args) -> T` running the first `["feature"] => body` whose feature the CPU has
/// (checked at run time, in order), else the `_ => body`. Each body sees the arguments by name
/// and is compiled with its feature enabled, so what it inlines is vectorised for it. With
/// `["feature", ...] { body }` the one body is compiled for each feature and the baseline.
macro_rules! by_cpu {
    // One body for every form.
    ($(#[$attr:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) -> $ret:ty
        [$($feature:tt),+] $body:block) => {
        $(#[$attr])*
        $vis fn $name($($arg: $ty),*) -> $ret {
            #[inline(always)]
            fn body($($arg: $ty),*) -> $ret $body
            $crate::simd::by_cpu!(@same ($($arg: $ty),*) -> $ret; $($feature),+)
        }
    };
    // A body per form.
    ($(#[$attr:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) -> $ret:ty { $($forms:tt)* }) => {
        $(#[$attr])*
        $vis fn $name($($arg: $ty),*) -> $ret {
            $crate::simd::by_cpu!(@try ($($arg: $ty),*) -> $ret; $($forms)*)
        }
    };
    // The forms one at a time (a repetition over the features cannot hold one over the arguments).
    (@try ($($arg:ident: $ty:ty),*) -> $ret:ty; [$feature:tt] => $fast:expr, $($rest:tt)*) => {{
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = $feature)]
            unsafe fn fast($($arg: $ty),*) -> $ret {
                $fast
            }
            if std::arch::is_x86_feature_detected!($feature) {
                // SAFETY: the CPU has the feature the function is compiled for.
                return unsafe { fast($($arg),*) };
            }
        }
        $crate::simd::by_cpu!(@try ($($arg: $ty),*) -> $ret; $($rest)*)
    }};
    (@try ($($arg:ident: $ty:ty),*) -> $ret:ty; _ => $base:expr $(,)?) => {
        $base
    };
    (@same ($($arg:ident: $ty:ty),*) -> $ret:ty; $feature:tt $(, $rest:tt)*) => {
        $crate::simd::by_cpu!(@try ($($arg: $ty),*) -> $ret; [$feature] => body($($arg),*), _ => {
            $crate::simd::by_cpu!(@same ($($arg: $ty),*) -> $ret; $($rest),*)
        })
    };
    (@same ($($arg:ident: $ty:ty),*) -> $ret:ty;) => {
        body($($arg),*)
    };
}
pub(crate) use by_cpu;
