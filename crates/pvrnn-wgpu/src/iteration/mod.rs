//! A whole learning iteration on the device: the recurrence's weights and every training
//! sequence's adaptive variables stay there with their RAdam moments, beside the read-outs
//! ([`crate::learner`]), so that an iteration uploads only its eps and a small table, runs
//! in one submission (inputs packed from the adaptive variables and eps, the recurrence
//! forward, both read-outs from the module states in its record, their d F / d d into the
//! recurrence's backward pass, the recurrent weights' and the adaptive variables'
//! gradients) and reads back only what the free energy needs: the read-outs' row losses
//! and the KL terms per step and unit (summed on the host in f64, as the CPU backend sums
//! them). Values move between the kernels' layouts with `shaders/strided_copy.wgsl`.
//!
//! Several learning runs of one shape (a cohort: an experiment condition's networks, other
//! seeds) share a [`Stack`]: their recurrent weights, one network after another in the same
//! buffers, and the recurrence's buffers likewise, so that one forward and one backward
//! dispatch run every window of every network (a workgroup each: the recurrence is a
//! chain of dependent steps, and one network's 18 windows leave most of a GPU idle). Each
//! run prepares its part of an iteration (its inputs, read-outs and gradients' copies) when
//! it begins; the first to wait for its result submits every prepared run's at once.
//!
//! Files:
//! - `stack.rs`: what a cohort shares on the device ([`Stack`]), and the work queued in it.
//! - `queue.rs`: runs' prepared iterations queued, submitted together, their results
//!   claimed by ticket (or withdrawn).
//! - `submit.rs`: one submission of every prepared run's iteration, the recurrence's part
//!   recorded and replayed.
//! - `run.rs`: one learning run on the device ([`DeviceIteration`]) and its free energy.
//! - `prepare.rs`: a run's part of an iteration, encoded once and replayed.
//! - `dispatches.rs`: the dispatches of a run's part, and the refresh of the transposed
//!   weights after an update.
//! - `record_readout.rs`: a read-out encoded from the module states in a recurrence record.

mod dispatches;
mod prepare;
mod queue;
mod record_readout;
mod run;
mod stack;
mod submit;

pub(crate) use run::DeviceIteration;
pub(crate) use stack::Stack;
