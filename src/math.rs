//! Float math in one place: `libm` underneath so the crate works without `std`, and a [`Real`]
//! trait so the physics runs the same code in `f32` and `f64`.

use core::ops::{Add, AddAssign, Div, Mul, MulAssign, Neg, Sub, SubAssign};

/// A floating-point scalar (`f32` or `f64`).
pub trait Real:
    Copy
    + PartialOrd
    + Default
    + core::fmt::Debug
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + SubAssign
    + MulAssign
    + Send
    + Sync
    + 'static
{
    /// 0.
    const ZERO: Self;
    /// 1.
    const ONE: Self;
    /// Conversion from `f64` (rounding for `f32`).
    fn from_f64(x: f64) -> Self;
    /// Conversion from `f32` (exact).
    fn from_f32(x: f32) -> Self;
    /// Conversion to `f64` (exact).
    fn to_f64(self) -> f64;
    /// Square root.
    fn sqrt(self) -> Self;
    /// Absolute value.
    fn abs(self) -> Self;
    /// Four-quadrant arctangent of `self / x`.
    fn atan2(self, x: Self) -> Self;
    /// Natural logarithm.
    fn ln(self) -> Self;
    /// Exponential.
    fn exp(self) -> Self;
    /// Larger of two (NaN-ignoring like `f32::max`).
    fn max(self, o: Self) -> Self;
    /// Smaller of two.
    fn min(self, o: Self) -> Self;
    /// True unless NaN or infinite.
    fn is_finite(self) -> bool;
}

macro_rules! impl_real {
    ($t:ty, $sqrt:path, $atan2:path, $ln:path, $exp:path) => {
        impl Real for $t {
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            #[inline(always)]
            fn from_f64(x: f64) -> Self {
                x as $t
            }
            #[inline(always)]
            fn from_f32(x: f32) -> Self {
                x as $t
            }
            #[inline(always)]
            fn to_f64(self) -> f64 {
                self as f64
            }
            #[inline(always)]
            fn sqrt(self) -> Self {
                $sqrt(self)
            }
            #[inline(always)]
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
            #[inline(always)]
            fn atan2(self, x: Self) -> Self {
                $atan2(self, x)
            }
            #[inline(always)]
            fn ln(self) -> Self {
                $ln(self)
            }
            #[inline(always)]
            fn exp(self) -> Self {
                $exp(self)
            }
            #[inline(always)]
            fn max(self, o: Self) -> Self {
                <$t>::max(self, o)
            }
            #[inline(always)]
            fn min(self, o: Self) -> Self {
                <$t>::min(self, o)
            }
            #[inline(always)]
            fn is_finite(self) -> bool {
                <$t>::is_finite(self)
            }
        }
    };
}

impl_real!(f32, sqrt_f32, libm::atan2f, libm::logf, libm::expf);
impl_real!(f64, sqrt_f64, libm::atan2, libm::log, libm::exp);

// Square roots go through the compiler's own intrinsic where the target's baseline has the
// instruction: `libm`'s x86 version is inline assembly of the legacy-SSE `sqrtss`, which the
// compiler can neither vectorise nor encode as VEX inside AVX code, and on Intel cores a legacy
// SSE instruction after 512-bit code stalls (the LayerNorm statistics of the h = 32 edge MLP
// spent half their time there). Both are correctly rounded: the results are the same bits.

/// Square root of an `f32`, correctly rounded.
#[inline(always)]
pub fn sqrt_f32(x: f32) -> f32 {
    #[cfg(all(target_arch = "x86_64", target_feature = "sse"))]
    {
        use core::arch::x86_64::{_mm_cvtss_f32, _mm_set_ss, _mm_sqrt_ss};
        // SAFETY: SSE is in the target's baseline (the `cfg` above).
        unsafe { _mm_cvtss_f32(_mm_sqrt_ss(_mm_set_ss(x))) }
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "sse")))]
    {
        libm::sqrtf(x)
    }
}

/// Square root of an `f64`, correctly rounded.
#[inline(always)]
pub fn sqrt_f64(x: f64) -> f64 {
    #[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
    {
        use core::arch::x86_64::{_mm_cvtsd_f64, _mm_set_sd, _mm_sqrt_pd};
        // SAFETY: SSE2 is in the target's baseline (the `cfg` above).
        unsafe { _mm_cvtsd_f64(_mm_sqrt_pd(_mm_set_sd(x))) }
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
    {
        libm::sqrt(x)
    }
}

/// A 3-vector of [`Real`]s, for code generic over precision (glam covers the `f32` fast paths).
pub type V3<T> = [T; 3];

/// `a - b`.
#[inline(always)]
pub fn sub3<T: Real>(a: V3<T>, b: V3<T>) -> V3<T> {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `a + b`.
#[inline(always)]
pub fn add3<T: Real>(a: V3<T>, b: V3<T>) -> V3<T> {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// `-a`.
#[inline(always)]
pub fn neg3<T: Real>(a: V3<T>) -> V3<T> {
    [-a[0], -a[1], -a[2]]
}

/// `a * s`.
#[inline(always)]
pub fn scale3<T: Real>(a: V3<T>, s: T) -> V3<T> {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// Dot product.
#[inline(always)]
pub fn dot3<T: Real>(a: V3<T>, b: V3<T>) -> T {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Cross product.
#[inline(always)]
pub fn cross3<T: Real>(a: V3<T>, b: V3<T>) -> V3<T> {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// Euclidean length.
#[inline(always)]
pub fn norm3<T: Real>(a: V3<T>) -> T {
    dot3(a, a).sqrt()
}

/// Converts an `f32` triple to any [`Real`].
#[inline(always)]
pub fn v3_from_f32<T: Real>(a: [f32; 3]) -> V3<T> {
    [T::from_f32(a[0]), T::from_f32(a[1]), T::from_f32(a[2])]
}

/// True when all three components are finite.
#[inline(always)]
pub fn finite3(a: [f32; 3]) -> bool {
    a[0].is_finite() && a[1].is_finite() && a[2].is_finite()
}

/// Bounding box `(lo, hi)` of the finite points of `points` (m); all zero when there is none.
pub fn finite_bounds(points: &[[f32; 3]]) -> ([f32; 3], [f32; 3]) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in points {
        for k in 0..3 {
            if p[k].is_finite() {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
    }
    if lo[0] > hi[0] {
        return ([0.0; 3], [0.0; 3]);
    }
    (lo, hi)
}

#[cfg(test)]
mod tests {
    use super::{sqrt_f32, sqrt_f64};
    use crate::rng::Rng;

    /// The instruction path gives `libm`'s bits on every class of input: the physics' parity with
    /// the reference does not depend on which one a target uses.
    #[test]
    fn sqrt_matches_libm_bit_for_bit() {
        let special32 = [0.0f32, -0.0, 1.0, 4.0, f32::MIN_POSITIVE, 1e-45, f32::MAX, f32::INFINITY, -1.0, f32::NAN];
        let mut rng = Rng::new(7);
        let random32 = (0..10_000).map(|_| f32::from_bits(rng.next_u64() as u32 & 0x7FFF_FFFF));
        for x in special32.into_iter().chain(random32) {
            let (a, b) = (sqrt_f32(x), libm::sqrtf(x));
            assert!(a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()), "sqrt_f32({x:e}) = {a:e}, libm {b:e}");
        }
        let special64 = [0.0f64, -0.0, 2.0, f64::MIN_POSITIVE, 5e-324, f64::MAX, f64::INFINITY, -2.0, f64::NAN];
        let random64 = (0..10_000).map(|_| f64::from_bits(rng.next_u64() & 0x7FFF_FFFF_FFFF_FFFF));
        for x in special64.into_iter().chain(random64) {
            let (a, b) = (sqrt_f64(x), libm::sqrt(x));
            assert!(a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()), "sqrt_f64({x:e}) = {a:e}, libm {b:e}");
        }
    }
}
