//! A run's part of an iteration prepared: eps flattened and checked against the sequences
//! the run holds, what starts from zero cleared, and its dispatches encoded once into a
//! [`Recording`] and replayed while the data and their shapes stay.

use std::sync::Arc;

use pvrnn_core::data::Observations;
use pvrnn_core::{Error, Result};

use crate::encode::DispatchList;
use crate::output::EncodedReadout;
use crate::pool::PooledBuffer;

use super::dispatches::Batch;
use super::run::{DeviceIteration, Recording};
use super::stack::{Prepared, Reading, RunWork};

impl DeviceIteration {
    /// The device work of one iteration of this run, encoded (or replayed from its
    /// [`Recording`]), with what reading its results needs ([`RunWork`]).
    pub(super) fn prepare(
        &self,
        data: &Observations<f32>,
        eps: &[[Vec<f32>; 4]],
    ) -> Result<Prepared> {
        let stack = &*self.stack;
        let gpu = &*stack.gpu;
        let batch = Batch::of(self.layout(), data.lengths(), stack.entry_base(self.slot));
        let _phase =
            pvrnn_core::profile::phase("evaluate on the device: a run's part, encoded or replayed");
        let (eps_flat, per_module_at) = self.flatten_eps(&batch, eps)?;
        let key = (data.id(), batch.lengths.to_vec(), eps_flat.len());
        let mut clears = gpu.device.create_command_encoder(&Default::default());
        self.clear(&mut clears);
        let mut recording = self.recording.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(r) = recording.as_ref().filter(|r| r.key == key) {
            return Ok(self.replay(r, &eps_flat, clears));
        }
        gpu.count_iteration_encoded();
        let eps_buffer = gpu.upload("eps", &eps_flat);
        let mut keep: Vec<PooledBuffer> = Vec::new();
        let mut inputs = DispatchList::default();
        self.encode_inputs(
            gpu,
            &mut inputs,
            &batch,
            &eps_buffer,
            &per_module_at,
            &mut keep,
        );
        let mut readout_work = DispatchList::default();
        let mut readout_clears = Vec::new();
        let readouts = self.encode_readouts(
            gpu,
            &mut readout_clears,
            &mut readout_work,
            &batch,
            data,
            &mut keep,
        )?;
        for buffer in &readout_clears {
            clears.clear_buffer(buffer, 0, None);
        }
        let mut after = DispatchList::default();
        self.encode_adaptive_grads(gpu, &mut after, &batch, &mut keep);
        let kl = self.encode_kl_terms(gpu, &mut after, &batch, &per_module_at, &mut keep);
        let mut sources = vec![((*kl).clone(), eps_flat.len())];
        sources.extend(
            readouts
                .iter()
                .map(|(r, _)| ((*r.row_loss).clone(), batch.total)),
        );
        self.encode_finite_checks(gpu, &mut after, &sources, &mut keep);
        let divisors = [readouts[0].1, readouts[1].1];
        keep.push(kl);
        let readouts: Vec<EncodedReadout> = readouts.into_iter().map(|(r, _)| r).collect();
        let work = RunWork {
            inputs: Arc::new(inputs),
            readouts: Arc::new(readout_work),
            after: Arc::new(after),
            entries: batch.entries,
            sources,
            reading: Reading {
                total: batch.total,
                per_module_at,
                divisors,
            },
        };
        let prepared = Prepared {
            ticket: 0,
            slot: self.slot,
            clears: Some(clears.finish()),
            work: work.clone(),
        };
        // The buffers stay with the recording, for the next iterations.
        *recording = Some(Recording {
            key,
            eps: eps_buffer,
            clears: readout_clears,
            work,
            marks: self.readouts.learner_marks(),
            _keep: keep,
            _readouts: readouts,
        });
        Ok(prepared)
    }

    /// `r` prepared again: eps written into its buffer (before the submission that uses
    /// it runs: queue order), its clears added to `clears`, the learner's marks set again.
    fn replay(
        &self,
        r: &Recording,
        eps_flat: &[f32],
        mut clears: wgpu::CommandEncoder,
    ) -> Prepared {
        let gpu = &*self.stack.gpu;
        gpu.queue
            .write_buffer(&r.eps, 0, bytemuck::cast_slice(eps_flat));
        for buffer in &r.clears {
            clears.clear_buffer(buffer, 0, None);
        }
        self.readouts.set_learner_marks(r.marks);
        Prepared {
            ticket: 0,
            slot: self.slot,
            clears: Some(clears.finish()),
            work: r.work.clone(),
        }
    }

    /// Whether `data` and `eps` fit the sequences this learner holds.
    pub(super) fn check_fits(&self, data: &Observations<f32>, eps: &[[Vec<f32>; 4]]) -> Result<()> {
        let lengths = data.lengths();
        let (sequences, steps) = (self.stack.sequences, self.stack.steps);
        if data.sequences() != sequences || data.steps() > steps {
            return Err(Error::Mismatch(format!(
                "the learner holds adaptive variables for {sequences} sequences of {steps} steps, but the data has {} sequences of {} steps",
                data.sequences(),
                data.steps()
            )));
        }
        if lengths.contains(&0) || eps.len() != lengths.len() {
            return Err(Error::Mismatch(
                "every training sequence needs at least one step and its eps".into(),
            ));
        }
        Ok(())
    }

    /// eps per module, `[steps of every window, z]`, and where each module's block starts
    /// (the KL terms come back in the same layout).
    fn flatten_eps(
        &self,
        batch: &Batch<'_>,
        eps: &[[Vec<f32>; 4]],
    ) -> Result<(Vec<f32>, [usize; 4])> {
        let modules = self.layout().modules();
        let mut per_module_at = [0usize; 4];
        let mut flat = Vec::with_capacity(batch.total * modules.iter().map(|m| m.z).sum::<usize>());
        for (m, ml) in modules.iter().enumerate() {
            per_module_at[m] = flat.len();
            for (w, &len) in batch.lengths.iter().enumerate() {
                let e = &eps[w][m];
                if e.len() < len * ml.z {
                    return Err(Error::Mismatch(format!(
                        "eps of sequence {w} is shorter than its {len} steps"
                    )));
                }
                flat.extend_from_slice(&e[..len * ml.z]);
            }
        }
        Ok((flat, per_module_at))
    }

    /// Clears what starts from zero: the run's inputs (initial states are zero), its
    /// read-outs' d F / d d (modules without a read-out get none), its adaptive gradients
    /// (steps past a sequence's length get none), its divergence mark.
    fn clear(&self, encoder: &mut wgpu::CommandEncoder) {
        let stack = &*self.stack;
        let s = self.layout().strides();
        let base = stack.entry_base(self.slot);
        let rows = stack.sequences * stack.steps;
        let inputs = stack.sequences * (s.init + stack.steps * s.input);
        encoder.clear_buffer(
            &stack.inputs,
            (4 * base[1]) as u64,
            Some((4 * inputs) as u64),
        );
        encoder.clear_buffer(
            &stack.grad_d,
            (4 * base[4]) as u64,
            Some((4 * rows * s.grad_d) as u64),
        );
        for pair in &self.adaptive_grads {
            for grads in pair {
                encoder.clear_buffer(grads, 0, None);
            }
        }
        // The update after this evaluation reads this evaluation's mark only.
        encoder.clear_buffer(&self.diverged, 0, None);
    }
}
