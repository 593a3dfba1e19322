//! The table the recurrence kernels read (`Table` in `shaders/recurrence_common.wgsl`, field
//! for field): the modules' shapes and offsets, the strides, the ablation, then one entry
//! per window; built from a [`RecurrenceLayout`] and uploaded.

use bytemuck::{Pod, Zeroable};
use pvrnn_core::data::Ablation;

use crate::gpu::Gpu;
use crate::pool::PooledBuffer;

use super::layout::{RecurrenceLayout, WindowEntry};

/// Where the window table starts, and its words per window (see
/// `shaders/recurrence_common.wgsl`).
pub(super) const TABLE_WINDOWS: usize = std::mem::size_of::<Table>() / 4;
pub(super) const WINDOW_WORDS: usize = std::mem::size_of::<TableWindow>() / 4;

/// The recurrence kernels' table (`Table` in `shaders/recurrence_common.wgsl`, field for
/// field), followed by one [`TableWindow`] per window.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Table {
    windows: u32,
    /// 1 if module m is ablated.
    ablated: [u32; 4],
    strides: Strides32,
    /// Module m's offset within a step of the read-out gradients.
    grad_d_at: [u32; 4],
    pad: [u32; 2],
    modules: [TableModule; 4],
}

/// [`Strides`](super::layout::Strides) as the kernels read them.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Strides32 {
    record: u32,
    input: u32,
    init: u32,
    grad_d: u32,
    back: u32,
}

/// A module in the kernels' table (`Module` in the WGSL): sizes, weight offsets, offsets
/// within a step (see [`ModuleLayout`](super::layout::ModuleLayout)).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct TableModule {
    d: u32,
    z: u32,
    /// 4 = none.
    parent: u32,
    parent_d: u32,
    w_prior: u32,
    b_prior: u32,
    w_dd: u32,
    w_dz: u32,
    w_dh: u32,
    bias: u32,
    inv_tau: u32,
    decay: u32,
    record: u32,
    input: u32,
    init: u32,
    back: u32,
}

/// A window in the kernels' table (`WindowInfo` in the WGSL).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct TableWindow {
    steps: u32,
    inputs: u32,
    record: u32,
    /// 1 if the window's posterior is the prior.
    prior: u32,
    grad_d: u32,
    back: u32,
    /// Where the window's network's weights start (a cohort's networks in one dispatch).
    weights: u32,
    pad: u32,
}

impl RecurrenceLayout {
    /// The table the kernels read (`Table` in `shaders/recurrence_common.wgsl`): modules,
    /// strides, ablation, then `windows` as (steps, inputs, record, prior posterior,
    /// read-out gradients, backward record) offsets.
    fn table(&self, ablation: &Ablation, windows: &[WindowEntry]) -> Vec<u32> {
        let s = &self.strides;
        let word = |v: usize| v as u32;
        let header = Table {
            windows: word(windows.len()),
            ablated: ablation.0.map(u32::from),
            strides: Strides32 {
                record: word(s.record),
                input: word(s.input),
                init: word(s.init),
                grad_d: word(s.grad_d),
                back: word(s.back),
            },
            grad_d_at: std::array::from_fn(|m| word(self.modules[m].grad_d)),
            pad: [0; 2],
            modules: std::array::from_fn(|m| {
                let ml = &self.modules[m];
                TableModule {
                    d: word(ml.d),
                    z: word(ml.z),
                    parent: word(ml.parent.unwrap_or(4)),
                    parent_d: word(ml.parent_d),
                    w_prior: word(ml.w_prior),
                    b_prior: word(ml.b_prior),
                    w_dd: word(ml.w_dd),
                    w_dz: word(ml.w_dz),
                    w_dh: word(ml.w_dh),
                    bias: word(ml.bias),
                    inv_tau: word(ml.inv_tau),
                    decay: word(ml.decay),
                    record: word(ml.record),
                    input: word(ml.input),
                    init: word(ml.init),
                    back: word(ml.back),
                }
            }),
        };
        let mut t: Vec<u32> = bytemuck::cast_slice(bytemuck::bytes_of(&header)).to_vec();
        for w in windows {
            let entry = TableWindow {
                steps: word(w[0]),
                inputs: word(w[1]),
                record: word(w[2]),
                prior: word(w[3]),
                grad_d: word(w[4]),
                back: word(w[5]),
                weights: word(w[6]),
                pad: 0,
            };
            t.extend_from_slice(bytemuck::cast_slice(bytemuck::bytes_of(&entry)));
        }
        t
    }

    /// The windows' table, uploaded.
    pub(crate) fn upload_table(
        &self,
        gpu: &Gpu,
        ablation: &Ablation,
        entries: &[WindowEntry],
    ) -> PooledBuffer {
        gpu.upload("recurrence table", &self.table(ablation, entries))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The WGSL structs have no padding of their own (every field a u32 or an array of
    /// them), so the kernels read these at the same word offsets as the Rust structs give.
    #[test]
    fn the_table_s_rust_structs_have_the_wgsl_layout() {
        assert_eq!(std::mem::size_of::<TableModule>(), 16 * 4);
        assert_eq!(std::mem::size_of::<TableWindow>(), 8 * 4);
        // windows count, 4 ablated, 5 strides, 4 offsets, 2 pad, then 4 modules.
        assert_eq!(std::mem::size_of::<Table>(), (16 + 4 * 16) * 4);
        let common = shader!("recurrence_common.wgsl");
        for name in ["struct Table {", "struct Module {", "struct WindowInfo {"] {
            assert!(common.contains(name), "{name} is gone from the WGSL");
        }
    }
}
