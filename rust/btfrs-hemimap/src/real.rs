//! The scalar trait the maps are generic over.
//!
//! A deliberately tiny stand-in for `num_traits::Float`: only the operations the concentric maps
//! need, implemented for `f32` and `f64`. The trait is sealed so that new methods can be added
//! without breaking anyone; downstream code can still write `T: Real` bounds.

use core::fmt::Debug;
use core::ops::{Add, Div, Mul, Neg, Sub};

mod sealed {
    pub trait Sealed {}
    impl Sealed for f32 {}
    impl Sealed for f64 {}
}

/// A floating-point scalar (`f32` or `f64`) the maps of this crate are generic over.
///
/// `Send + Sync` are supertraits so that the batch functions can hand slices of `T` to rayon.
pub trait Real:
    sealed::Sealed
    + Copy
    + Send
    + Sync
    + Debug
    + PartialOrd
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + 'static
{
    /// 0.
    const ZERO: Self;
    /// 1/2.
    const HALF: Self;
    /// 1.
    const ONE: Self;
    /// 2.
    const TWO: Self;
    /// pi / 4.
    const FRAC_PI_4: Self;
    /// pi / 2.
    const FRAC_PI_2: Self;
    /// pi.
    const PI: Self;
    /// 2 pi.
    const TAU: Self;
    /// 4 / pi.
    const FRAC_4_PI: Self;

    /// Converts from `f64`, rounding to nearest.
    fn from_f64(v: f64) -> Self;
    /// Converts to `f64` (exact).
    fn to_f64(self) -> f64;
    /// Absolute value.
    fn abs(self) -> Self;
    /// Square root (NaN for negative input).
    fn sqrt(self) -> Self;
    /// `(sin self, cos self)`.
    fn sin_cos(self) -> (Self, Self);
    /// Four-quadrant arctangent of `self / x`, in `[-pi, pi]`; `atan2(0, 0) = 0`.
    fn atan2(self, x: Self) -> Self;
    /// Clamps into `[lo, hi]`; NaN stays NaN. `lo <= hi` is the caller's (this crate's) duty.
    fn clamp(self, lo: Self, hi: Self) -> Self;
    /// Neither NaN nor infinite.
    fn is_finite(self) -> bool;
}

macro_rules! impl_real {
    ($t:ident) => {
        impl Real for $t {
            const ZERO: Self = 0.0;
            const HALF: Self = 0.5;
            const ONE: Self = 1.0;
            const TWO: Self = 2.0;
            const FRAC_PI_4: Self = core::$t::consts::FRAC_PI_4;
            const FRAC_PI_2: Self = core::$t::consts::FRAC_PI_2;
            const PI: Self = core::$t::consts::PI;
            const TAU: Self = core::$t::consts::TAU;
            // 4/pi = 2 * (2/pi); doubling is exact, so this is 4/pi correctly rounded.
            const FRAC_4_PI: Self = 2.0 * core::$t::consts::FRAC_2_PI;

            #[inline(always)]
            fn from_f64(v: f64) -> Self {
                v as $t
            }
            #[inline(always)]
            fn to_f64(self) -> f64 {
                self as f64
            }
            #[inline(always)]
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
            #[inline(always)]
            fn sqrt(self) -> Self {
                <$t>::sqrt(self)
            }
            #[inline(always)]
            fn sin_cos(self) -> (Self, Self) {
                <$t>::sin_cos(self)
            }
            #[inline(always)]
            fn atan2(self, x: Self) -> Self {
                <$t>::atan2(self, x)
            }
            #[inline(always)]
            fn is_finite(self) -> bool {
                <$t>::is_finite(self)
            }
            #[inline(always)]
            fn clamp(self, lo: Self, hi: Self) -> Self {
                // Written with comparisons instead of `<$t>::clamp`, which panics on bad bounds.
                if self < lo {
                    lo
                } else if self > hi {
                    hi
                } else {
                    self
                }
            }
        }
    };
}

impl_real!(f32);
impl_real!(f64);
