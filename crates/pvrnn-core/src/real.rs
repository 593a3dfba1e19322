//! The floating-point types the model runs in.
//!
//! Models are stored and run in `f32`; `f64` exists so that gradient checks by finite
//! differences are exact to ~1e-8 instead of drowning in f32 rounding.

use std::fmt;

use crate::kernels;

/// A float the model can be computed in (`f32` or `f64`).
pub trait Real:
    faer::traits::RealField + Copy + Default + Send + Sync + fmt::Debug + fmt::Display + 'static
{
    const ZERO: Self;
    const ONE: Self;
    fn from_f64(v: f64) -> Self;
    fn to_f64(self) -> f64;
    fn from_f32(v: f32) -> Self;
    fn to_f32(self) -> f32;
    /// exp; for f32 a vectorisable approximation accurate to ~2 ulp on [-87, 88] (clamped
    /// outside, so it never overflows).
    fn exp(self) -> Self;
    fn sqrt(self) -> Self;
    /// tanh; for f32 a rational approximation accurate to a few ulp that vectorises.
    fn tanh(self) -> Self;
    fn is_finite(self) -> bool;
    /// `self * b + c`, fused where the target has FMA in hardware (x86-64 inside the
    /// kernels' SIMD dispatch); a plain multiply-add elsewhere (wasm has no scalar FMA).
    fn madd(self, b: Self, c: Self) -> Self;

    /// `xs[i] = tanh(xs[i])`, vectorised where the CPU allows.
    fn tanh_in_place(xs: &mut [Self]);

    /// Standard normals from uniform 32-bit words (Box-Muller); `bits` holds
    /// `2 * ceil(out.len() / 2)` words.
    fn normals_from_bits(bits: &[u32], out: &mut [Self]);

    /// The fused output-layer kernel of learning and inference.
    ///
    /// On entry `pre` holds output pre-activations; on exit it holds
    /// `d loss / d pre = scale * (y - x) * (1 - y^2)` with `y = tanh(pre)`.
    /// Returns `sum (y - x)^2` (unscaled). `ahead` (possibly empty) is a later row's
    /// targets, fetched into cache while this runs (a hint: no effect on the results).
    fn output_error(pre: &mut [Self], target: &[Self], ahead: &[Self], scale: Self) -> f64;
}

impl Real for f32 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    #[inline(always)]
    fn from_f64(v: f64) -> Self {
        v as f32
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self as f64
    }
    #[inline(always)]
    fn from_f32(v: f32) -> Self {
        v
    }
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self
    }
    #[inline(always)]
    fn exp(self) -> Self {
        kernels::exp_f32(self)
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f32::sqrt(self)
    }
    #[inline(always)]
    fn tanh(self) -> Self {
        kernels::tanh_f32(self)
    }
    #[inline(always)]
    fn is_finite(self) -> bool {
        f32::is_finite(self)
    }
    #[inline(always)]
    fn madd(self, b: Self, c: Self) -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            f32::mul_add(self, b, c)
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            self * b + c
        }
    }
    fn tanh_in_place(xs: &mut [Self]) {
        kernels::tanh_in_place_f32(xs)
    }
    fn output_error(pre: &mut [Self], target: &[Self], ahead: &[Self], scale: Self) -> f64 {
        kernels::output_error_f32(pre, target, ahead, scale)
    }
    fn normals_from_bits(bits: &[u32], out: &mut [Self]) {
        kernels::box_muller_f32(bits, out)
    }
}

impl Real for f64 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    #[inline(always)]
    fn from_f64(v: f64) -> Self {
        v
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self
    }
    #[inline(always)]
    fn from_f32(v: f32) -> Self {
        v as f64
    }
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
    #[inline(always)]
    fn exp(self) -> Self {
        f64::exp(self)
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    #[inline(always)]
    fn tanh(self) -> Self {
        f64::tanh(self)
    }
    #[inline(always)]
    fn is_finite(self) -> bool {
        f64::is_finite(self)
    }
    #[inline(always)]
    fn madd(self, b: Self, c: Self) -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            f64::mul_add(self, b, c)
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            self * b + c
        }
    }
    fn tanh_in_place(xs: &mut [Self]) {
        for x in xs {
            *x = x.tanh();
        }
    }
    fn normals_from_bits(bits: &[u32], out: &mut [Self]) {
        // Same words, same formula as f32, in full precision.
        let half = out.len() / 2;
        let normal = |b1: u32, b2: u32| {
            let u1 = (b1 as f64 + 1.0) / 4_294_967_296.0;
            let u2 = (b2 >> 8) as f64 / 16_777_216.0;
            let r = (-2.0 * u1.ln()).sqrt();
            let a = std::f64::consts::TAU * u2;
            (r * a.cos(), r * a.sin())
        };
        for i in 0..half {
            let (z0, z1) = normal(bits[i], bits[half + i]);
            out[i] = z0;
            out[half + i] = z1;
        }
        if out.len() % 2 == 1 {
            out[2 * half] = normal(bits[2 * half], bits[2 * half + 1]).0;
        }
    }

    fn output_error(pre: &mut [Self], target: &[Self], ahead: &[Self], scale: Self) -> f64 {
        kernels::prefetch(ahead);
        let mut sum = 0.0;
        for (p, &x) in pre.iter_mut().zip(target) {
            let y = p.tanh();
            let e = y - x;
            sum += e * e;
            *p = scale * e * (1.0 - y * y);
        }
        sum
    }
}
