//! One submission of every prepared run's iteration: their inputs, one forward and one
//! backward dispatch of the recurrence over all their windows, their read-outs, the weight
//! gradients and copies, in one compute pass (while profiling, a pass per part or per
//! kernel, each timed), and one read-back; the recurrence's part recorded and replayed while
//! the same runs make it up.

use std::sync::Arc;

use pvrnn_core::data::Ablation;

use crate::encode::DispatchList;
use crate::readback::read_back;
use crate::recurrence::{WeightGradBuffers, WindowEntry};
use crate::timing::{PassTimes, begin_pass};

use super::stack::{InFlight, Prepared, RecordedRecurrence, RecurrenceWork, Stack};

impl Stack {
    /// Every prepared run's iteration in one submission: their inputs, one forward dispatch
    /// over all their windows, their read-outs, one backward dispatch, each run's weight
    /// gradients and copies; then one read-back of every run's free-energy terms, not yet
    /// waited for.
    pub(super) fn submit(&self, mut prepared: Vec<Prepared>) -> InFlight {
        let gpu = &*self.gpu;
        let clears: Vec<wgpu::CommandBuffer> = prepared
            .iter_mut()
            .filter_map(|p| p.clears.take())
            .collect();
        let encode_phase = pvrnn_core::profile::phase("evaluate on the device: upload and encode");
        let recurrence_phase = pvrnn_core::profile::phase(
            "evaluate on the device: the recurrence's part, encoded or replayed",
        );
        let recurrence = self.recurrence_work(&prepared);
        drop(recurrence_phase);
        let RecurrenceWork {
            forward,
            backward,
            weight_grads,
            ..
        } = &*recurrence;
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        // Dispatches in one compute pass (a pass per dispatch costs the host more than the
        // small kernels); while profiling, a pass per part, each timed on the device.
        let parts: [(&'static str, Vec<&DispatchList>); 6] = [
            (
                "device: inputs into the recurrence's layout",
                prepared.iter().map(|p| &*p.work.inputs).collect(),
            ),
            ("device: recurrence forward", vec![forward]),
            (
                "device: read-outs (hidden and output layers, forward and backward)",
                prepared.iter().map(|p| &*p.work.readouts).collect(),
            ),
            ("device: recurrence backward", vec![backward]),
            ("device: recurrent weight gradients", vec![weight_grads]),
            (
                "device: gradients into the optimiser's layout",
                prepared.iter().map(|p| &*p.work.after).collect(),
            ),
        ];
        let (times, per_kernel) = self.pass_times(&parts);
        match &times {
            None => {
                let mut pass = begin_pass(&mut encoder, None, 0);
                parts
                    .iter()
                    .flat_map(|(_, lists)| lists)
                    .for_each(|list| list.replay(&mut pass));
            }
            Some(times) if per_kernel => {
                let dispatches = parts
                    .iter()
                    .flat_map(|(_, lists)| lists)
                    .flat_map(|list| (0..list.len()).map(move |index| (list, index)));
                for (pass_index, (list, index)) in dispatches.enumerate() {
                    let mut pass = begin_pass(&mut encoder, Some(times), pass_index);
                    list.replay_one(index, &mut pass);
                }
                times.resolve(&mut encoder);
            }
            Some(times) => {
                for (part, (_, lists)) in parts.iter().enumerate() {
                    let mut pass = begin_pass(&mut encoder, Some(times), part);
                    lists.iter().for_each(|list| list.replay(&mut pass));
                }
                times.resolve(&mut encoder);
            }
        }
        drop(parts);
        let sources: Vec<(&wgpu::Buffer, usize)> = prepared
            .iter()
            .flat_map(|p| p.work.sources.iter().map(|(b, n)| (b, *n)))
            .collect();
        // The clears first, then the iteration (queue order).
        gpu.queue.submit(clears);
        let read_back = read_back(gpu, encoder, &sources);
        if let Some(times) = times {
            times.collect(gpu);
        }
        drop(encode_phase);
        InFlight {
            tickets: prepared
                .iter()
                .map(|p| (Some(p.ticket), p.work.sources.len()))
                .collect(),
            read_back,
            _prepared: prepared,
            _recurrence: recurrence,
        }
    }

    /// The timestamps of a submission's passes while profiling: a pass per part, or with
    /// `WgpuOptions::profile_kernels` a pass per dispatch (then `true`), its time added to its
    /// part and to its kernel. A submission of more dispatches than one query set times
    /// (wgpu's `QUERY_SET_MAX_QUERIES`, two queries each) is timed per part.
    fn pass_times(
        &self,
        parts: &[(&'static str, Vec<&DispatchList>)],
    ) -> (Option<PassTimes>, bool) {
        // Not profiling (every iteration but a bench's): nothing to name or count.
        if !pvrnn_core::profile::enabled() {
            return (None, false);
        }
        let dispatches: usize = parts
            .iter()
            .flat_map(|(_, lists)| lists)
            .map(|list| list.len())
            .sum();
        let per_kernel =
            self.profile_kernels && 2 * dispatches <= wgpu::QUERY_SET_MAX_QUERIES as usize;
        let passes: Vec<Vec<&'static str>> = if per_kernel {
            let kernels = &self.gpu.kernel_names;
            parts
                .iter()
                .flat_map(|(part, lists)| {
                    lists
                        .iter()
                        .flat_map(|list| list.kernels())
                        .map(|kernel| vec![*part, kernels.phase(kernel)])
                })
                .collect()
        } else {
            parts.iter().map(|(part, _)| vec![*part]).collect()
        };
        (PassTimes::adding_to(&self.gpu, passes), per_kernel)
    }

    /// The recurrence's part of a submission for these runs: the one recorded for the same
    /// runs and windows when replaying, else encoded anew (and recorded).
    fn recurrence_work(&self, prepared: &[Prepared]) -> Arc<RecurrenceWork> {
        let mut recorded = self
            .recurrence_recording
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        let same_runs = |last: &&RecordedRecurrence| {
            last.runs.len() == prepared.len()
                && last
                    .runs
                    .iter()
                    .zip(prepared)
                    .all(|((slot, entries), p)| *slot == p.slot && *entries == p.work.entries)
        };
        if let Some(last) = recorded.as_ref().filter(same_runs) {
            return last.work.clone();
        }
        let work = Arc::new(self.encode_recurrence(prepared));
        *recorded = Some(RecordedRecurrence {
            runs: prepared
                .iter()
                .map(|p| (p.slot, p.work.entries.clone()))
                .collect(),
            work: work.clone(),
        });
        work
    }

    /// The recurrence's part of a submission for every prepared run: the windows' table,
    /// one forward and one backward dispatch over all their windows, and the weight
    /// gradients of each run; with the buffers to keep until the submission has run.
    fn encode_recurrence(&self, prepared: &[Prepared]) -> RecurrenceWork {
        let gpu = &*self.gpu;
        gpu.count_recurrence_part_encoded();
        let entries: Vec<WindowEntry> = prepared
            .iter()
            .flat_map(|p| p.work.entries.clone())
            .collect();
        let windows = entries.len();
        let layout = &self.layout;
        let table = layout.upload_table(gpu, &Ablation::none(), &entries);
        let mut keep = Vec::new();
        let mut forward = DispatchList::default();
        layout.encode_forward(
            gpu,
            &self.kernels,
            &mut forward,
            &table,
            &self.weights_t,
            &self.inputs,
            &self.record,
            windows,
        );
        let mut backward = DispatchList::default();
        keep.push(layout.encode_backward(
            gpu,
            &self.kernels,
            &mut backward,
            &table,
            &self.weights,
            &self.record,
            &self.grad_d,
            &self.back,
            windows,
        ));
        let mut first = 0;
        let networks: Vec<_> = prepared
            .iter()
            .map(|p| {
                let count = p.work.entries.len();
                first += count;
                (first - count..first, p.slot * self.weight_floats())
            })
            .collect();
        let buffers = WeightGradBuffers {
            table: &table,
            inputs: &self.inputs,
            record: &self.record,
            back: &self.back,
            grads: &self.grads,
        };
        let mut weight_grads = DispatchList::default();
        keep.extend(layout.encode_weight_grads(
            gpu,
            &self.kernels,
            &mut weight_grads,
            buffers,
            &networks,
        ));
        keep.push(table);
        RecurrenceWork {
            forward,
            backward,
            weight_grads,
            _buffers: keep,
        }
    }
}
