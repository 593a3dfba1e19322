//! The stack's queue: a run's prepared iteration enqueued under a ticket, every prepared one
//! submitted at once (by the first run to wait, or ahead), the read-back shared out by
//! ticket, and what a run gave up on withdrawn ([`Ticket`]).

use pvrnn_core::Result;

use super::stack::{InFlight, Prepared, Queue, Stack};

impl Stack {
    /// Queues a run's prepared iteration; its ticket claims the result.
    pub(super) fn enqueue(&self, mut prepared: Prepared) -> u64 {
        let mut queue = self.queue.lock().unwrap_or_else(|e| e.into_inner());
        prepared.ticket = queue.next_ticket;
        queue.next_ticket += 1;
        let ticket = prepared.ticket;
        queue.prepared.push(prepared);
        ticket
    }

    /// Submits every prepared iteration (one submission), without waiting.
    pub(crate) fn submit_prepared(&self) {
        let mut queue = self.queue.lock().unwrap_or_else(|e| e.into_inner());
        self.submit_locked(&mut queue);
    }

    /// Submitting allocates too (the recurrence's scratch, the read-back): where the
    /// device runs out of memory, the submission's iterations fail with that error when
    /// their results are claimed ([`Self::results_of`]), instead of wgpu's panic.
    fn submit_locked(&self, queue: &mut Queue) {
        let prepared = std::mem::take(&mut queue.prepared);
        if prepared.is_empty() {
            return;
        }
        let tickets: Vec<u64> = prepared.iter().map(|p| p.ticket).collect();
        let what = || match self.slots {
            1 => "submit a learning iteration".to_string(),
            n => format!("submit a learning iteration of {n} networks trained together"),
        };
        match self.gpu.allocating(what, || self.submit(prepared)) {
            Ok(in_flight) => queue.in_flight.push(in_flight),
            Err(error) => {
                let message = match error {
                    pvrnn_core::Error::Device(message) => message,
                    other => other.to_string(),
                };
                for ticket in tickets {
                    queue.failed.insert(ticket, message.clone());
                }
            }
        }
    }

    /// The read-back of `ticket`'s iteration: submitted with every other prepared one if it
    /// has not been yet, waited for (with the submissions before it).
    fn results_of(&self, ticket: u64) -> Result<Vec<Vec<f32>>> {
        let results = self.read_results_of(ticket)?;
        // A device that failed (out of memory outside the checked scopes, a read-back
        // refused) gave results that mean nothing.
        match self.gpu.failure() {
            Some(failure) => Err(failure),
            None => Ok(results),
        }
    }

    /// [`Self::results_of`] as they came back.
    fn read_results_of(&self, ticket: u64) -> Result<Vec<Vec<f32>>> {
        let mut queue = self.queue.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(results) = queue.results.remove(&ticket) {
            return Ok(results);
        }
        if queue.prepared.iter().any(|p| p.ticket == ticket) {
            self.submit_locked(&mut queue);
        }
        if let Some(message) = queue.failed.remove(&ticket) {
            return Err(pvrnn_core::Error::Device(message));
        }
        let holds = |f: &InFlight| f.tickets.iter().any(|&(t, _)| t == Some(ticket));
        let Some(last) = queue.in_flight.iter().position(holds) else {
            return Err(pvrnn_core::Error::Device(format!(
                "{}: a learning iteration's results were claimed but never submitted",
                self.gpu.describe()
            )));
        };
        let _phase = pvrnn_core::profile::phase("evaluate on the device: run and read back");
        for in_flight in queue.in_flight.drain(..=last).collect::<Vec<_>>() {
            let mut all = pvrnn_core::deferred::now(in_flight.read_back).into_iter();
            for (t, parts) in in_flight.tickets {
                let results: Vec<Vec<f32>> = all.by_ref().take(parts).collect();
                if let Some(t) = t {
                    queue.results.insert(t, results);
                }
            }
        }
        queue.results.remove(&ticket).ok_or_else(|| {
            pvrnn_core::Error::Device(format!(
                "{}: a learning iteration's results did not come back",
                self.gpu.describe()
            ))
        })
    }

    /// Takes `ticket`'s iteration back: not submitted if it was not yet, its results not
    /// kept if it was.
    pub(super) fn withdraw(&self, ticket: u64) {
        let mut queue = self.queue.lock().unwrap_or_else(|e| e.into_inner());
        queue.prepared.retain(|p| p.ticket != ticket);
        queue.failed.remove(&ticket);
        queue.results.remove(&ticket);
        for in_flight in &mut queue.in_flight {
            for (t, _) in &mut in_flight.tickets {
                if *t == Some(ticket) {
                    *t = None;
                }
            }
        }
    }
}

/// A run's claim on its prepared iteration's results ([`Stack::enqueue`]). Dropped before
/// they are taken (a caller that gave up on the future), it withdraws the iteration, or
/// its results, so that nothing stale is submitted or kept.
pub(super) struct Ticket<'s> {
    pub(super) stack: &'s Stack,
    pub(super) ticket: u64,
}

impl Ticket<'_> {
    pub(super) fn results(&self) -> Result<Vec<Vec<f32>>> {
        self.stack.results_of(self.ticket)
    }
}

impl Drop for Ticket<'_> {
    fn drop(&mut self) {
        self.stack.withdraw(self.ticket);
    }
}
