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
use crate::kernels::LANES;
use crate::parallel;
use crate::params::{Dense, ReadoutParams};

const COL_BLOCK: usize = 512;
const ROW_BLOCK: usize = 512;
/// Output columns per parallel group (about); groups never depend on the thread count, so
/// results do not either.
const GROUP_COLUMNS: usize = 768;
const MAX_GROUPS: usize = 16;

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

/// Gradients of one dense layer.
#[derive(Debug)]
pub(crate) struct DenseGrads<T> {
    pub(crate) weight: Vec<T>,
    pub(crate) bias: Option<Vec<T>>,
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
#[derive(Debug)]
pub(crate) struct OutputLoss<T> {
    /// Per row: (1/k) * sum 1/2 (x - y)^2.
    pub(crate) row_loss: Vec<f64>,
    /// d F / d input, `[n, hidden]`.
    pub(crate) grad_in: Vec<T>,
    /// d F / d W for the first k rows of W, `[k, hidden]`.
    pub(crate) grad_w: Option<Vec<T>>,
    pub(crate) grad_b: Option<Vec<T>>,
}

/// The fused, tiled output layer. `targets[r]` holds at least `k` values.
pub(crate) fn output_loss<T: Real>(
    out: &Dense<T>,
    input: &[T],
    n: usize,
    k: usize,
    targets: &[&[T]],
    weight_grads: bool,
) -> OutputLoss<T> {
    let hl = out.weight.shape()[1];
    let w = out.weight.data();
    let bias = out.bias.as_ref().map(|b| b.data());
    let scale = T::from_f64(1.0 / k as f64);
    // Groups split the columns in whole vector-width units.
    let units = k.div_ceil(LANES);
    let groups = k.div_ceil(GROUP_COLUMNS).clamp(1, MAX_GROUPS.min(units));
    let macs = n * k * hl * if weight_grads { 3 } else { 2 };
    let parts = parallel::map_if(macs >= parallel::PARALLEL_MIN_MACS, groups, |g| {
        let c_begin = (g * units / groups * LANES).min(k);
        let c_end = ((g + 1) * units / groups * LANES).min(k);
        let mut grad_in = vec![T::ZERO; n * hl];
        let mut sse = vec![0f64; n];
        let mut gw = vec![
            T::ZERO;
            if weight_grads {
                (c_end - c_begin) * hl
            } else {
                0
            }
        ];
        let mut gb = vec![
            T::ZERO;
            if weight_grads && bias.is_some() {
                c_end - c_begin
            } else {
                0
            }
        ];
        let mut tile = vec![T::ZERO; ROW_BLOCK.min(n) * COL_BLOCK.min(k)];
        for c0 in (c_begin..c_end).step_by(COL_BLOCK) {
            let cw = COL_BLOCK.min(c_end - c0);
            let w_blk = MatRef::from_row_major_slice(&w[c0 * hl..(c0 + cw) * hl], cw, hl);
            for r0 in (0..n).step_by(ROW_BLOCK) {
                let rw = ROW_BLOCK.min(n - r0);
                let x_blk = MatRef::from_row_major_slice(&input[r0 * hl..(r0 + rw) * hl], rw, hl);
                let tile = &mut tile[..rw * cw];
                faer::linalg::matmul::matmul(
                    MatMut::from_row_major_slice_mut(tile, rw, cw),
                    Accum::Replace,
                    x_blk,
                    w_blk.transpose(),
                    T::ONE,
                    Par::Seq,
                );
                for i in 0..rw {
                    let row = &mut tile[i * cw..(i + 1) * cw];
                    if let Some(b) = bias {
                        for (v, &bi) in row.iter_mut().zip(&b[c0..c0 + cw]) {
                            *v += bi;
                        }
                    }
                    sse[r0 + i] += T::output_error(row, &targets[r0 + i][c0..c0 + cw], scale);
                }
                let g_pre = MatRef::from_row_major_slice(tile, rw, cw);
                if weight_grads {
                    let off = (c0 - c_begin) * hl;
                    faer::linalg::matmul::matmul(
                        MatMut::from_row_major_slice_mut(&mut gw[off..off + cw * hl], cw, hl),
                        Accum::Add,
                        g_pre.transpose(),
                        x_blk,
                        T::ONE,
                        Par::Seq,
                    );
                    if bias.is_some() {
                        let sums = column_sums(tile, cw);
                        for (acc, s) in gb[c0 - c_begin..c0 - c_begin + cw].iter_mut().zip(sums) {
                            *acc += s;
                        }
                    }
                }
                faer::linalg::matmul::matmul(
                    MatMut::from_row_major_slice_mut(&mut grad_in[r0 * hl..(r0 + rw) * hl], rw, hl),
                    Accum::Add,
                    g_pre,
                    w_blk,
                    T::ONE,
                    Par::Seq,
                );
            }
        }
        (grad_in, sse, gw, gb)
    });

    let mut parts = parts.into_iter();
    let (mut grad_in, mut sse, mut grad_w, mut grad_b) = parts.next().expect("at least one group");
    for (gi, s, gw, gb) in parts {
        for (a, b) in grad_in.iter_mut().zip(gi) {
            *a += b;
        }
        for (a, b) in sse.iter_mut().zip(s) {
            *a += b;
        }
        grad_w.extend(gw);
        grad_b.extend(gb);
    }
    let half_over_k = 0.5 / k as f64;
    OutputLoss {
        row_loss: sse.into_iter().map(|s| s * half_over_k).collect(),
        grad_in,
        grad_w: weight_grads.then_some(grad_w),
        grad_b: (weight_grads && bias.is_some()).then_some(grad_b),
    }
}

/// Predictions of every output dimension for `n` rows: `tanh(input @ W^T + b)`.
pub(crate) fn output_predict<T: Real>(out: &Dense<T>, input: &[T], n: usize) -> Vec<T> {
    dense_forward(out, input, n, true, true)
}
