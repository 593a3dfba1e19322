//! Read-outs (eqs. 11-13) batched over rows (steps x sequences), forward and backward.
//!
//! The vision output layer is the model's whole cost: in learning it is
//! `[5400 x 50] @ [50 x 32256]` forward and two products of the same size backward. It is
//! computed in tiles so the `[rows x 32256]` prediction and error matrices never exist: each
//! tile is multiplied, turned into its error gradient by one fused pass, and consumed by the
//! two backward products while still in cache. Tiles are grouped by output columns; each
//! group is one parallel task with its own partial input-gradient, summed in group order.

use faer::{Accum, MatMut, MatRef, Par};

use crate::Real;
use crate::assembled::{DenseGrads, OutputLoss};
use crate::kernels::{LANES, simd};
use crate::parallel;
use crate::params::{Dense, ReadoutParams};

const COL_BLOCK: usize = 512;
const ROW_BLOCK: usize = 512;
/// Output columns per parallel group (about); groups never depend on the thread count, so
/// results do not either.
const GROUP_COLUMNS: usize = 768;
const MAX_GROUPS: usize = 16;
/// How many rows ahead the output layer prefetches its targets.
const TARGET_PREFETCH_ROWS: usize = 6;

/// `out [n, w] = act(input [n, k] @ W^T + b)`.
fn dense_forward<T: Real>(
    layer: &Dense<T>,
    input: &[T],
    n: usize,
    tanh: bool,
    par: bool,
) -> Vec<T> {
    let (w, k) = (layer.weight.shape()[0], layer.weight.shape()[1]);
    let mut out = vec![T::ZERO; n * w];
    faer::linalg::matmul::matmul(
        MatMut::from_row_major_slice_mut(&mut out, n, w),
        Accum::Replace,
        MatRef::from_row_major_slice(input, n, k),
        MatRef::from_row_major_slice(layer.weight.data(), w, k).transpose(),
        T::ONE,
        if par {
            parallel::gemm_par(2 * n * w * k)
        } else {
            Par::Seq
        },
    );
    if let Some(b) = &layer.bias {
        for row in out.chunks_exact_mut(w) {
            for (o, &bi) in row.iter_mut().zip(b.data()) {
                *o += bi;
            }
        }
    }
    if tanh {
        T::tanh_in_place(&mut out);
    }
    out
}

/// Activations of every hidden layer, bottom first, each `[n, width]`.
pub(crate) fn hidden_forward<T: Real>(r: &ReadoutParams<T>, input: &[T], n: usize) -> Vec<Vec<T>> {
    let mut acts: Vec<Vec<T>> = Vec::with_capacity(r.hidden.len());
    for layer in &r.hidden {
        let x = acts.last().map(Vec::as_slice).unwrap_or(input);
        acts.push(dense_forward(layer, x, n, true, true));
    }
    acts
}

/// Back through the hidden layers. `grad_top` is d F / d (top hidden activation).
/// Returns d F / d input and, if asked, each layer's gradients.
pub(crate) fn hidden_backward<T: Real>(
    r: &ReadoutParams<T>,
    input: &[T],
    n: usize,
    acts: &[Vec<T>],
    grad_top: Vec<T>,
    weight_grads: bool,
) -> (Vec<T>, Vec<DenseGrads<T>>) {
    let mut grad = grad_top;
    let mut layer_grads = Vec::new();
    for (k, layer) in r.hidden.iter().enumerate().rev() {
        let (w, fan_in) = (layer.weight.shape()[0], layer.weight.shape()[1]);
        // Through tanh: d pre = d act * (1 - act^2).
        for (g, &a) in grad.iter_mut().zip(&acts[k]) {
            *g *= T::ONE - a * a;
        }
        let x = if k == 0 { input } else { &acts[k - 1] };
        let g_pre = MatRef::from_row_major_slice(&grad, n, w);
        if weight_grads {
            let mut gw = vec![T::ZERO; w * fan_in];
            faer::linalg::matmul::matmul(
                MatMut::from_row_major_slice_mut(&mut gw, w, fan_in),
                Accum::Replace,
                g_pre.transpose(),
                MatRef::from_row_major_slice(x, n, fan_in),
                T::ONE,
                parallel::gemm_par(2 * n * w * fan_in),
            );
            let gb = layer.bias.as_ref().map(|_| column_sums(&grad, w));
            layer_grads.push(DenseGrads {
                weight: gw,
                bias: gb,
            });
        }
        let mut g_in = vec![T::ZERO; n * fan_in];
        faer::linalg::matmul::matmul(
            MatMut::from_row_major_slice_mut(&mut g_in, n, fan_in),
            Accum::Replace,
            g_pre,
            MatRef::from_row_major_slice(layer.weight.data(), w, fan_in),
            T::ONE,
            parallel::gemm_par(2 * n * w * fan_in),
        );
        grad = g_in;
    }
    layer_grads.reverse();
    (grad, layer_grads)
}

fn column_sums<T: Real>(m: &[T], cols: usize) -> Vec<T> {
    let mut s = vec![T::ZERO; cols];
    for row in m.chunks_exact(cols) {
        for (acc, &v) in s.iter_mut().zip(row) {
            *acc += v;
        }
    }
    s
}

/// Loss and gradients of the output layer on its first `k` (observed) outputs.
/// The fused, tiled output layer. `targets[r]` holds at least `k` values; each row's
/// summed squared error is divided by `divisor` (k, or the modality's full dimension).
/// `out_t` is the output weight transposed (`[hidden, dims]`); with it, few rows and no
/// weight gradients (online inference) use the small-row kernels instead of faer.
pub(crate) fn output_loss<T: Real>(
    out: &Dense<T>,
    out_t: Option<&[T]>,
    input: &[T],
    n: usize,
    k: usize,
    divisor: usize,
    targets: &[&[T]],
    weight_grads: bool,
) -> OutputLoss<T> {
    let hl = out.weight.shape()[1];
    let layer = FusedLayer {
        w: out.weight.data(),
        bias: out.bias.as_ref().map(|b| b.data()),
        hl,
        dims: out.weight.shape()[0],
        small: out_t.filter(|_| n <= SMALL_ROWS && !weight_grads),
        scale: T::from_f64(1.0 / divisor as f64),
        weight_grads,
    };
    // Groups split the columns in whole vector-width units.
    let units = k.div_ceil(LANES);
    let groups = k.div_ceil(GROUP_COLUMNS).clamp(1, MAX_GROUPS.min(units));
    let macs = n * k * hl * if weight_grads { 3 } else { 2 };
    let parts = parallel::map_if(macs >= parallel::PARALLEL_MIN_MACS, groups, |g| {
        let c_begin = (g * units / groups * LANES).min(k);
        let c_end = ((g + 1) * units / groups * LANES).min(k);
        let mut acc = GroupSums::new(&layer, n, c_end - c_begin);
        let mut tile = vec![T::ZERO; ROW_BLOCK.min(n) * COL_BLOCK.min(k)];
        for c0 in (c_begin..c_end).step_by(COL_BLOCK) {
            let cw = COL_BLOCK.min(c_end - c0);
            for r0 in (0..n).step_by(ROW_BLOCK) {
                let rw = ROW_BLOCK.min(n - r0);
                let block = Block {
                    r0,
                    rw,
                    c0,
                    cw,
                    c_begin,
                };
                layer.tile(&mut tile[..rw * cw], &block, input, targets, &mut acc);
            }
        }
        acc
    });

    let mut parts = parts.into_iter();
    let mut sums = parts.next().expect("at least one group");
    for part in parts {
        for (a, b) in sums.grad_in.iter_mut().zip(part.grad_in) {
            *a += b;
        }
        for (a, b) in sums.sse.iter_mut().zip(part.sse) {
            *a += b;
        }
        sums.gw.extend(part.gw);
        sums.gb.extend(part.gb);
    }
    let half_over_k = 0.5 / divisor as f64;
    OutputLoss {
        row_loss: sums.sse.into_iter().map(|s| s * half_over_k).collect(),
        grad_in: sums.grad_in,
        grad_w: weight_grads.then_some(sums.gw),
        grad_b: (weight_grads && layer.bias.is_some()).then_some(sums.gb),
    }
}

/// The output layer as the fused kernel reads it.
struct FusedLayer<'a, T> {
    /// `[dims, hl]` row-major, and the bias.
    w: &'a [T],
    bias: Option<&'a [T]>,
    hl: usize,
    dims: usize,
    /// W^T, when the small-row kernels replace faer.
    small: Option<&'a [T]>,
    /// 1 / divisor: each row's error gradient's factor.
    scale: T,
    weight_grads: bool,
}

/// One tile of rows x columns of the output layer.
#[derive(Clone, Copy)]
struct Block {
    r0: usize,
    rw: usize,
    c0: usize,
    cw: usize,
    /// The first column of the tile's group.
    c_begin: usize,
}

/// What one column group accumulates: d F / d input (all rows), the rows' squared errors,
/// and its columns' weight and bias gradients.
struct GroupSums<T> {
    grad_in: Vec<T>,
    sse: Vec<f64>,
    gw: Vec<T>,
    gb: Vec<T>,
}

impl<T: Real> GroupSums<T> {
    fn new(layer: &FusedLayer<'_, T>, n: usize, columns: usize) -> Self {
        let grads = layer.weight_grads;
        Self {
            grad_in: vec![T::ZERO; n * layer.hl],
            sse: vec![0f64; n],
            gw: vec![T::ZERO; if grads { columns * layer.hl } else { 0 }],
            gb: vec![
                T::ZERO;
                if grads && layer.bias.is_some() {
                    columns
                } else {
                    0
                }
            ],
        }
    }
}

impl<T: Real> FusedLayer<'_, T> {
    /// One tile: forward, error and its gradient in place, then (while in cache) the
    /// weight gradient and d F / d input products.
    fn tile(
        &self,
        tile: &mut [T],
        b: &Block,
        input: &[T],
        targets: &[&[T]],
        acc: &mut GroupSums<T>,
    ) {
        let (hl, Block { r0, rw, c0, cw, .. }) = (self.hl, *b);
        let w_blk = MatRef::from_row_major_slice(&self.w[c0 * hl..(c0 + cw) * hl], cw, hl);
        let x_blk = MatRef::from_row_major_slice(&input[r0 * hl..(r0 + rw) * hl], rw, hl);
        match self.small {
            Some(wt) => small_forward(
                tile,
                &input[r0 * hl..(r0 + rw) * hl],
                rw,
                hl,
                wt,
                self.dims,
                c0,
                cw,
            ),
            None => faer::linalg::matmul::matmul(
                MatMut::from_row_major_slice_mut(tile, rw, cw),
                Accum::Replace,
                x_blk,
                w_blk.transpose(),
                T::ONE,
                Par::Seq,
            ),
        }
        for i in 0..rw {
            // The targets are read once per pass, a short run of each distant row: fetch a
            // later row's run while this one computes, or the loads stall.
            let ahead = targets
                .get(r0 + i + TARGET_PREFETCH_ROWS)
                .map_or(&[][..], |t| &t[c0..c0 + cw]);
            let row = &mut tile[i * cw..(i + 1) * cw];
            if let Some(bias) = self.bias {
                for (v, &bi) in row.iter_mut().zip(&bias[c0..c0 + cw]) {
                    *v += bi;
                }
            }
            acc.sse[r0 + i] +=
                T::output_error(row, &targets[r0 + i][c0..c0 + cw], ahead, self.scale);
        }
        let g_pre = MatRef::from_row_major_slice(tile, rw, cw);
        if self.weight_grads {
            let off = (c0 - b.c_begin) * hl;
            faer::linalg::matmul::matmul(
                MatMut::from_row_major_slice_mut(&mut acc.gw[off..off + cw * hl], cw, hl),
                Accum::Add,
                g_pre.transpose(),
                x_blk,
                T::ONE,
                Par::Seq,
            );
            if self.bias.is_some() {
                let sums = column_sums(tile, cw);
                let at = c0 - b.c_begin;
                for (a, s) in acc.gb[at..at + cw].iter_mut().zip(sums) {
                    *a += s;
                }
            }
        }
        let g_in = &mut acc.grad_in[r0 * hl..(r0 + rw) * hl];
        if self.small.is_some() {
            small_backward(g_in, tile, rw, hl, &self.w[c0 * hl..(c0 + cw) * hl], cw);
        } else {
            faer::linalg::matmul::matmul(
                MatMut::from_row_major_slice_mut(g_in, rw, hl),
                Accum::Add,
                g_pre,
                w_blk,
                T::ONE,
                Par::Seq,
            );
        }
    }
}

/// Rows up to which the small-row kernels replace faer (online inference windows).
pub(crate) const SMALL_ROWS: usize = 64;

/// Register tiles of the small-row kernels (rows x columns of accumulators), chosen by
/// measurement in V8: each weight vector loaded is used for several rows, and the tile fits
/// the 16 SIMD registers. About twice the speed of plain axpy loops, and four times faer's
/// (scalar in wasm) at these shapes.
const FORWARD_TILE: (usize, usize) = (4, 8);
const BACKWARD_TILE: (usize, usize) = (2, 16);

/// `y[i, ..cw] = x[i, :] @ wt[:, c0..c0 + cw]` (`wt` = W^T, row stride `dims`). Every output
/// sums over the hidden units in order, so the tiling does not change a single bit.
fn small_forward<T: Real>(
    y: &mut [T],
    x: &[T],
    n: usize,
    hl: usize,
    wt: &[T],
    dims: usize,
    c0: usize,
    cw: usize,
) {
    const R: usize = FORWARD_TILE.0;
    const C: usize = FORWARD_TILE.1;
    simd(
        #[inline(always)]
        || {
            let wt = &wt[c0..];
            let mut c = 0;
            while c + C <= cw {
                let mut i = 0;
                while i + R <= n {
                    forward_tile::<T, R, C>(y, x, hl, wt, dims, cw, i, c);
                    i += R;
                }
                for i in i..n {
                    forward_tile::<T, 1, C>(y, x, hl, wt, dims, cw, i, c);
                }
                c += C;
            }
            for c in c..cw {
                for i in 0..n {
                    forward_tile::<T, 1, 1>(y, x, hl, wt, dims, cw, i, c);
                }
            }
        },
    )
}

/// Rows `i..i + R` of `y`, columns `c..c + C`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn forward_tile<T: Real, const R: usize, const C: usize>(
    y: &mut [T],
    x: &[T],
    hl: usize,
    wt: &[T],
    dims: usize,
    cw: usize,
    i: usize,
    c: usize,
) {
    let mut acc = [[T::ZERO; C]; R];
    for j in 0..hl {
        let w: &[T; C] = wt[j * dims + c..j * dims + c + C]
            .try_into()
            .expect("C columns");
        for q in 0..R {
            let a = x[(i + q) * hl + j];
            for l in 0..C {
                acc[q][l] = a.madd(w[l], acc[q][l]);
            }
        }
    }
    for (q, row) in acc.iter().enumerate() {
        y[(i + q) * cw + c..(i + q) * cw + c + C].copy_from_slice(row);
    }
}

/// `gx[i, :] += e[i, ..cw] @ w[..cw, :]` (`w` = W's rows of these columns, `[cw, hl]`), in
/// column order per output, as `small_forward`.
fn small_backward<T: Real>(gx: &mut [T], e: &[T], n: usize, hl: usize, w: &[T], cw: usize) {
    const R: usize = BACKWARD_TILE.0;
    simd(
        #[inline(always)]
        || {
            let mut i = 0;
            while i + R <= n {
                backward_rows(gx, e, hl, w, cw, i, R);
                i += R;
            }
            for i in i..n {
                backward_rows(gx, e, hl, w, cw, i, 1);
            }
        },
    )
}

/// Rows `i..i + count` of `gx`, every hidden unit. Inlined into the kernels' SIMD dispatch:
/// compiled apart from it, every `madd` would be a call to libm's `fmaf`.
#[inline(always)]
fn backward_rows<T: Real>(
    gx: &mut [T],
    e: &[T],
    hl: usize,
    w: &[T],
    cw: usize,
    i: usize,
    count: usize,
) {
    const C: usize = BACKWARD_TILE.1;
    let mut j = 0;
    while j + C <= hl {
        backward_tile::<T, C>(gx, e, hl, w, cw, i, count, j);
        j += C;
    }
    while j + 4 <= hl {
        backward_tile::<T, 4>(gx, e, hl, w, cw, i, count, j);
        j += 4;
    }
    for j in j..hl {
        backward_tile::<T, 1>(gx, e, hl, w, cw, i, count, j);
    }
}

/// Rows `i..i + count` (`count` <= 2) of `gx`, hidden units `j..j + C`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn backward_tile<T: Real, const C: usize>(
    gx: &mut [T],
    e: &[T],
    hl: usize,
    w: &[T],
    cw: usize,
    i: usize,
    count: usize,
    j: usize,
) {
    let load = |gx: &[T], q: usize| -> [T; C] {
        gx[(i + q) * hl + j..(i + q) * hl + j + C]
            .try_into()
            .expect("C units")
    };
    let mut a0 = load(gx, 0);
    if count == 2 {
        let mut a1 = load(gx, 1);
        let (e0, e1) = (&e[i * cw..(i + 1) * cw], &e[(i + 1) * cw..(i + 2) * cw]);
        for c in 0..cw {
            let wr: &[T; C] = w[c * hl + j..c * hl + j + C].try_into().expect("C units");
            let (x0, x1) = (e0[c], e1[c]);
            for l in 0..C {
                a0[l] = x0.madd(wr[l], a0[l]);
                a1[l] = x1.madd(wr[l], a1[l]);
            }
        }
        gx[(i + 1) * hl + j..(i + 1) * hl + j + C].copy_from_slice(&a1);
    } else {
        let e0 = &e[i * cw..(i + 1) * cw];
        for c in 0..cw {
            let wr: &[T; C] = w[c * hl + j..c * hl + j + C].try_into().expect("C units");
            for l in 0..C {
                a0[l] = e0[c].madd(wr[l], a0[l]);
            }
        }
    }
    gx[i * hl + j..i * hl + j + C].copy_from_slice(&a0);
}

/// Predictions of every output dimension for `n` rows: `tanh(input @ W^T + b)`. With `out_t`
/// (W^T) and few rows, the small-row kernel replaces faer, as in `output_loss`.
pub(crate) fn output_predict<T: Real>(
    out: &Dense<T>,
    out_t: Option<&[T]>,
    input: &[T],
    n: usize,
) -> Vec<T> {
    let Some(wt) = out_t.filter(|_| n <= SMALL_ROWS) else {
        return dense_forward(out, input, n, true, true);
    };
    let (dims, hl) = (out.weight.shape()[0], out.weight.shape()[1]);
    let mut y = vec![T::ZERO; n * dims];
    small_forward(&mut y, input, n, hl, wt, dims, 0, dims);
    if let Some(b) = &out.bias {
        for row in y.chunks_exact_mut(dims) {
            for (v, &bi) in row.iter_mut().zip(b.data()) {
                *v += bi;
            }
        }
    }
    T::tanh_in_place(&mut y);
    y
}

#[cfg(test)]
mod tests {
    use super::*;

    fn values(n: usize, seed: u32) -> Vec<f32> {
        (0..n)
            .map(|i| {
                ((i as u32).wrapping_mul(2_654_435_761).wrapping_add(seed) % 1000) as f32 / 500.0
                    - 1.0
            })
            .collect()
    }

    /// Odd sizes exercise every remainder path of the register tiles.
    #[test]
    fn small_kernels_match_plain_loops() {
        for &(n, hl, dims, c0, cw) in &[
            (7, 37, 40, 3, 29),
            (1, 5, 9, 0, 9),
            (4, 16, 8, 0, 8),
            (64, 20, 33, 1, 17),
        ] {
            let x = values(n * hl, 1);
            let wt = values(hl * dims, 2);
            let mut y = vec![0f32; n * cw];
            small_forward(&mut y, &x, n, hl, &wt, dims, c0, cw);
            for i in 0..n {
                for c in 0..cw {
                    let want: f32 = (0..hl).map(|j| x[i * hl + j] * wt[j * dims + c0 + c]).sum();
                    assert!(
                        (y[i * cw + c] - want).abs() < 1e-4,
                        "forward ({n},{hl},{cw}) [{i},{c}]"
                    );
                }
            }
            // W's rows for these columns, [cw, hl].
            let w: Vec<f32> = (0..cw)
                .flat_map(|c| (0..hl).map(|j| wt[j * dims + c0 + c]).collect::<Vec<_>>())
                .collect();
            let e = values(n * cw, 3);
            let start = values(n * hl, 4);
            let mut gx = start.clone();
            small_backward(&mut gx, &e, n, hl, &w, cw);
            for i in 0..n {
                for j in 0..hl {
                    let want = start[i * hl + j]
                        + (0..cw).map(|c| e[i * cw + c] * w[c * hl + j]).sum::<f32>();
                    assert!(
                        (gx[i * hl + j] - want).abs() < 1e-4,
                        "backward ({n},{hl},{cw}) [{i},{j}]"
                    );
                }
            }
        }
    }
}
