//! Small hand-written kernels: SIMD dispatch, axpy-form matrix-vector products and the
//! vectorised f32 tanh.
//!
//! Kernels accumulate element-wise (axpy form) rather than as horizontal reductions, so a
//! result does not depend on the vector width (SSE2, AVX2, AVX-512). Multiply-adds are
//! fused on x86-64 (see [`crate::Real::madd`]), like faer's products: runs are bit-for-bit
//! reproducible on one machine, not across CPUs with and without FMA.
//!
//! The one module allowed unsafe code (the workspace denies it): calling functions compiled
//! for CPU features checked at run time, and prefetch hints.
#![allow(unsafe_code)]

/// Runs `f` compiled for the widest x86 vector extension the CPU has (AVX-512, then AVX2),
/// else as is. `f` and everything it calls should be `#[inline(always)]` so the code is
/// generated inside the feature-enabled function.
#[inline(always)]
pub(crate) fn simd<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw,avx2,fma,bmi1,bmi2")]
        fn v4<R>(f: impl FnOnce() -> R) -> R {
            f()
        }
        #[target_feature(enable = "avx2,fma,bmi1,bmi2")]
        fn v3<R>(f: impl FnOnce() -> R) -> R {
            f()
        }
        if std::is_x86_feature_detected!("avx512f")
            && std::is_x86_feature_detected!("avx512vl")
            && std::is_x86_feature_detected!("avx512dq")
            && std::is_x86_feature_detected!("avx512bw")
            && std::is_x86_feature_detected!("avx2")
            && std::is_x86_feature_detected!("fma")
            && std::is_x86_feature_detected!("bmi1")
            && std::is_x86_feature_detected!("bmi2")
        {
            // SAFETY: the CPU supports every feature enabled on `v4`.
            return unsafe { v4(f) };
        }
        if std::is_x86_feature_detected!("avx2")
            && std::is_x86_feature_detected!("fma")
            && std::is_x86_feature_detected!("bmi1")
            && std::is_x86_feature_detected!("bmi2")
        {
            // SAFETY: the CPU supports every feature enabled on `v3`.
            return unsafe { v3(f) };
        }
    }
    f()
}

/// Asks the CPU to bring `data` into cache ahead of use; a hint with no effect on results
/// (and a no-op off x86-64).
#[inline(always)]
pub(crate) fn prefetch<T>(data: &[T]) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        let start = data.as_ptr().cast::<i8>();
        for offset in (0..std::mem::size_of_val(data)).step_by(64) {
            // SAFETY: a prefetch never faults, and the address lies inside `data`.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(start.add(offset)) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = data;
}

/// `y += a * x`
#[inline(always)]
pub(crate) fn axpy<T: crate::Real>(y: &mut [T], a: T, x: &[T]) {
    debug_assert_eq!(y.len(), x.len());
    for (yi, &xi) in y.iter_mut().zip(x) {
        *yi = a.madd(xi, *yi);
    }
}

/// Vector width the small kernels pad to (16 f32 = one AVX-512 register).
pub(crate) const LANES: usize = 16;

/// `n` rounded up to a multiple of [`LANES`].
pub(crate) fn padded(n: usize) -> usize {
    n.div_ceil(LANES) * LANES
}

/// `y[..stride] += sum_i x[i] * m[i, ..stride]` for row-major `m` with row stride `stride`
/// (a multiple of [`LANES`], padding columns zero).
///
/// With `m = W^T` (padded) this is the forward product `y += W x`; with `m = W` the
/// transposed product `y += W^T x`. Four rows are combined per pass over `y`; the sum is
/// grouped the same way on every instruction set, so results do not depend on it.
#[inline(always)]
pub(crate) fn gemv_padded<T: crate::Real>(y: &mut [T], m: &[T], x: &[T], stride: usize) {
    let y = &mut y[..stride];
    let m = &m[..x.len() * stride];
    let mut i = 0;
    while i + 4 <= x.len() {
        let (x0, x1, x2, x3) = (x[i], x[i + 1], x[i + 2], x[i + 3]);
        let (r0, rest) = m[i * stride..(i + 4) * stride].split_at(stride);
        let (r1, rest) = rest.split_at(stride);
        let (r2, r3) = rest.split_at(stride);
        for j in 0..stride {
            y[j] = x3.madd(r3[j], x2.madd(r2[j], x1.madd(r1[j], x0.madd(r0[j], y[j]))));
        }
        i += 4;
    }
    while i < x.len() {
        axpy(y, x[i], &m[i * stride..(i + 1) * stride]);
        i += 1;
    }
}

/// Copies row-major `[rows, cols]` into `[rows, stride]`, zero-padding each row.
pub(crate) fn pad_rows<T: crate::Real>(m: &[T], rows: usize, cols: usize, stride: usize) -> Vec<T> {
    let mut out = vec![T::ZERO; rows * stride];
    for r in 0..rows {
        out[r * stride..r * stride + cols].copy_from_slice(&m[r * cols..(r + 1) * cols]);
    }
    out
}

/// The transpose of row-major `[rows, cols]`, as `[cols, stride]` with zero padding.
pub(crate) fn transpose_padded<T: crate::Real>(
    m: &[T],
    rows: usize,
    cols: usize,
    stride: usize,
) -> Vec<T> {
    let mut out = vec![T::ZERO; cols * stride];
    for r in 0..rows {
        for c in 0..cols {
            out[c * stride + r] = m[r * cols + c];
        }
    }
    out
}

// Rational approximation of tanh on [-7.9, 7.9] (numerator degree 13, denominator 6); the
// coefficients are the classic minimax fit used by Eigen's fast float tanh. Max error is a
// few ulp, checked against f64 in the tests below.
const TANH_CLAMP: f32 = 7.905_311;
const A1: f32 = 4.893_524_6e-3;
const A3: f32 = 6.372_619_3e-4;
const A5: f32 = 1.485_722_4e-5;
const A7: f32 = 5.122_297e-8;
const A9: f32 = -8.604_672e-11;
const A11: f32 = 2.000_188e-13;
const A13: f32 = -2.760_768_5e-16;
const B0: f32 = 4.893_525e-3;
const B2: f32 = 2.268_434_6e-3;
const B4: f32 = 1.185_347_1e-4;
const B6: f32 = 1.198_258_4e-6;

/// Branch-free f32 tanh (vectorises).
#[inline(always)]
pub(crate) fn tanh_f32(x: f32) -> f32 {
    use crate::Real;
    let x = x.clamp(-TANH_CLAMP, TANH_CLAMP);
    let x2 = x * x;
    let p = x2.madd(
        x2.madd(x2.madd(x2.madd(x2.madd(x2.madd(A13, A11), A9), A7), A5), A3),
        A1,
    );
    let q = x2.madd(x2.madd(x2.madd(B6, B4), B2), B0);
    x * p / q
}

/// Branch-free f32 exp (vectorises): Cody-Waite range reduction, Cephes' degree-6
/// polynomial, and 2^n built from the exponent bits. Inputs are clamped to [-87, 88] so the
/// result stays a normal float. Max relative error ~2 ulp (checked below).
#[inline(always)]
pub(crate) fn exp_f32(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    // Adding and subtracting 1.5 * 2^23 rounds to the nearest integer without a libm call.
    const ROUND: f32 = 12_582_912.0;
    use crate::Real;
    let x = x.clamp(-87.0, 88.0);
    let n = x.madd(LOG2E, ROUND) - ROUND;
    let r = (-n).madd(LN2_LO, (-n).madd(LN2_HI, x));
    let p = r.madd(
        r.madd(
            r.madd(
                r.madd(r.madd(1.987_569_1e-4, 1.398_199_9e-3), 8.333_452e-3),
                4.166_579_6e-2,
            ),
            1.666_666_5e-1,
        ),
        5e-1,
    );
    let y = (p * r).madd(r, r) + 1.0;
    y * f32::from_bits(((n as i32 + 127) as u32) << 23)
}

/// Natural log for normal positive f32 (vectorises): exponent split, then
/// ln m = 2 atanh(s) with s = (m - 1) / (m + 1), |s| <= 0.172, to degree 9.
#[inline(always)]
pub(crate) fn ln_f32(x: f32) -> f32 {
    use crate::Real;
    let bits = x.to_bits();
    let mut e = ((bits >> 23) & 0xff) as i32 - 127;
    let mut m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000);
    let big = m > std::f32::consts::SQRT_2;
    m = if big { m * 0.5 } else { m };
    e += big as i32;
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let series = s2.madd(
        s2.madd(s2.madd(s2.madd(1.0 / 9.0, 1.0 / 7.0), 1.0 / 5.0), 1.0 / 3.0),
        1.0,
    );
    (e as f32).madd(std::f32::consts::LN_2, 2.0 * s * series)
}

/// (sin, cos) of 2 pi u for u in [0, 1) (vectorises): quadrant reduction to |theta| <= pi/4,
/// then Taylor polynomials (errors below 3e-8).
#[inline(always)]
pub(crate) fn sin_cos_2pi_f32(u: f32) -> (f32, f32) {
    use crate::Real;
    const ROUND: f32 = 12_582_912.0;
    let q = (u * 4.0 + ROUND) - ROUND;
    let theta = (u - q * 0.25) * std::f32::consts::TAU;
    let t2 = theta * theta;
    let s = theta
        * t2.madd(
            t2.madd(
                t2.madd(t2.madd(1.0 / 362_880.0, -1.0 / 5040.0), 1.0 / 120.0),
                -1.0 / 6.0,
            ),
            1.0,
        );
    let c = t2.madd(
        t2.madd(
            t2.madd(t2.madd(1.0 / 40_320.0, -1.0 / 720.0), 1.0 / 24.0),
            -0.5,
        ),
        1.0,
    );
    let quadrant = (q as i32) & 3;
    let (sin, cos) = if quadrant & 1 == 1 { (c, -s) } else { (s, c) };
    if quadrant & 2 == 2 {
        (-sin, -cos)
    } else {
        (sin, cos)
    }
}

/// Box-Muller: pairs of 32-bit uniforms to pairs of standard normals. `bits.len()` must be
/// `2 * ceil(out.len() / 2)`. |z| reaches 6.66 (u1 >= 2^-32).
pub(crate) fn box_muller_f32(bits: &[u32], out: &mut [f32]) {
    simd(
        #[inline(always)]
        || {
            let pairs = out.len() / 2;
            let (head, tail) = out.split_at_mut(pairs * 2);
            let (b1, b2) = bits[..2 * pairs].split_at(pairs);
            let (z0, z1) = head.split_at_mut(pairs);
            for i in 0..pairs {
                let (r, s, c) = box_muller_parts(b1[i], b2[i]);
                z0[i] = r * c;
                z1[i] = r * s;
            }
            if let Some(last) = tail.first_mut() {
                let (r, _, c) = box_muller_parts(bits[2 * pairs], bits[2 * pairs + 1]);
                *last = r * c;
            }
        },
    )
}

#[inline(always)]
fn box_muller_parts(b1: u32, b2: u32) -> (f32, f32, f32) {
    const TWO_M32: f32 = 1.0 / 4_294_967_296.0;
    let u1 = (b1 as f32 + 1.0) * TWO_M32;
    let u2 = (b2 >> 8) as f32 * (1.0 / 16_777_216.0);
    let r = (-2.0 * ln_f32(u1)).sqrt();
    let (s, c) = sin_cos_2pi_f32(u2);
    (r, s, c)
}

pub(crate) fn tanh_in_place_f32(xs: &mut [f32]) {
    simd(
        #[inline(always)]
        || {
            for x in xs.iter_mut() {
                *x = tanh_f32(*x);
            }
        },
    )
}

/// See [`crate::Real::output_error`]. Sixteen partial sums keep the reduction vectorised and
/// identical on every instruction set. `ahead` is fetched a cache line per 16 values
/// computed: issued at once, the fetches of a whole run stall on the CPU's few outstanding
/// misses.
pub(crate) fn output_error_f32(pre: &mut [f32], target: &[f32], ahead: &[f32], scale: f32) -> f64 {
    debug_assert_eq!(pre.len(), target.len());
    simd(
        #[inline(always)]
        || {
            const LANES: usize = 16;
            let mut acc = [0f32; LANES];
            let mut pre_chunks = pre.chunks_exact_mut(LANES);
            let mut target_chunks = target.chunks_exact(LANES);
            for (c, (p, x)) in (&mut pre_chunks).zip(&mut target_chunks).enumerate() {
                if let Some(line) = ahead.get(c * LANES..c * LANES + 1) {
                    prefetch(line);
                }
                for j in 0..LANES {
                    let y = tanh_f32(p[j]);
                    let e = y - x[j];
                    acc[j] += e * e;
                    p[j] = scale * e * (1.0 - y * y);
                }
            }
            let mut sum: f64 = acc.iter().map(|&a| a as f64).sum();
            for (p, &x) in pre_chunks
                .into_remainder()
                .iter_mut()
                .zip(target_chunks.remainder())
            {
                let y = tanh_f32(*p);
                let e = y - x;
                sum += (e * e) as f64;
                *p = scale * e * (1.0 - y * y);
            }
            sum
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    #[cfg(target_arch = "wasm32")]
    use wasm_bindgen_test::wasm_bindgen_test as test;

    #[test]
    fn tanh_f32_matches_f64_tanh() {
        let mut worst = 0f64;
        let mut x = -12.0f32;
        while x <= 12.0 {
            let err = (tanh_f32(x) as f64 - (x as f64).tanh()).abs();
            worst = worst.max(err);
            x += 0.000_37;
        }
        assert!(worst < 5e-7, "max abs error {worst}");
        assert_eq!(tanh_f32(0.0), 0.0);
        assert!(tanh_f32(100.0) <= 1.0 && tanh_f32(-100.0) >= -1.0);
    }

    #[test]
    fn exp_f32_matches_f64_exp() {
        let mut worst = 0f64;
        let mut x = -87.0f32;
        while x <= 88.0 {
            let want = (x as f64).exp();
            let rel = ((exp_f32(x) as f64 - want) / want).abs();
            worst = worst.max(rel);
            x += 0.001_37;
        }
        assert!(worst < 3e-7, "max relative error {worst}");
        assert_eq!(exp_f32(0.0), 1.0);
        assert!(exp_f32(-1000.0) > 0.0 && exp_f32(1000.0).is_finite());
    }

    #[test]
    fn ln_and_sin_cos_match_f64() {
        let mut worst_ln = 0f64;
        let mut x = 2.3e-10f32;
        while x <= 1.0 {
            worst_ln = worst_ln.max((ln_f32(x) as f64 - (x as f64).ln()).abs());
            x *= 1.000_37;
        }
        assert!(worst_ln < 2e-6, "ln abs error {worst_ln}");
        let mut worst_sc = 0f64;
        for i in 0..100_000 {
            let u = i as f32 / 100_000.0;
            let (s, c) = sin_cos_2pi_f32(u);
            let a = std::f64::consts::TAU * u as f64;
            worst_sc = worst_sc
                .max((s as f64 - a.sin()).abs())
                .max((c as f64 - a.cos()).abs());
        }
        assert!(worst_sc < 1e-6, "sin/cos abs error {worst_sc}");
    }

    #[test]
    fn box_muller_gives_standard_normals() {
        let mut s = 0x1234_5678_9abc_def0u64;
        let bits: Vec<u32> = (0..400_002)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 32) as u32
            })
            .collect();
        let mut z = vec![0f32; 400_001];
        box_muller_f32(&bits, &mut z);
        let n = z.len() as f64;
        let mean = z.iter().map(|&v| v as f64).sum::<f64>() / n;
        let var = z.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / n;
        let kurt = z.iter().map(|&v| (v as f64 - mean).powi(4)).sum::<f64>() / n / (var * var);
        let within_1 = z.iter().filter(|v| v.abs() < 1.0).count() as f64 / n;
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((var - 1.0).abs() < 0.01, "variance {var}");
        assert!((kurt - 3.0).abs() < 0.05, "kurtosis {kurt}");
        assert!((within_1 - 0.682_689).abs() < 0.005, "P(|z|<1) {within_1}");
    }

    #[test]
    fn output_error_matches_scalar_formula() {
        let pre: Vec<f32> = (0..37).map(|i| (i as f32 - 18.0) * 0.21).collect();
        let target: Vec<f32> = (0..37).map(|i| ((i * 7) % 11) as f32 * 0.1 - 0.5).collect();
        let mut got = pre.clone();
        let sum = output_error_f32(&mut got, &target, &target, 0.25);
        let mut want_sum = 0f64;
        for i in 0..37 {
            let y = (pre[i] as f64).tanh();
            let e = y - target[i] as f64;
            want_sum += e * e;
            let g = 0.25 * e * (1.0 - y * y);
            assert!((got[i] as f64 - g).abs() < 1e-6);
        }
        assert!((sum - want_sum).abs() < 1e-5);
    }
}
