//! Reading results back from the device: one mappable copy per call, as a future.
//!
//! Natively the future's first poll polls the device until the copy is mapped (also when
//! another thread's poll maps it), so it is ready then and synchronous callers finish it
//! with [`pvrnn_core::deferred::now`]; until it is polled, the host may queue more work. WebGPU maps
//! the copy when the browser's event loop runs: the future wakes its task then.
//!
//! A read-back that fails (the device lost, its mapping refused) records the device's
//! failure ([`Gpu::failure`]) and gives zeros of the right sizes, which whoever returns
//! results replaces with that failure: the callers' types stay those of a device that
//! cannot fail, and nothing it computed after failing is taken for a result.

use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll, Waker};

use crate::gpu::{Gpu, record_failure};
use crate::pool::PooledBuffer;

/// Copies `sources` (each `floats` long) into one mappable buffer and submits; awaiting it
/// gives them back in order.
pub(crate) fn read_back(
    gpu: &Gpu,
    mut encoder: wgpu::CommandEncoder,
    sources: &[(&wgpu::Buffer, usize)],
) -> ReadBack {
    let sizes: Vec<usize> = sources.iter().map(|&(_, n)| n).collect();
    let total: usize = sizes.iter().sum();
    let staging = gpu.staging(total);
    let mut offset = 0;
    for &(buffer, n) in sources {
        if n > 0 {
            encoder.copy_buffer_to_buffer(buffer, 0, &staging, (offset * 4) as u64, (n * 4) as u64);
        }
        offset += n;
    }
    // The profile's innermost phases (every read-back counts in them, the recurrence's
    // too): where a round trip's latency goes.
    let submit_phase = pvrnn_core::profile::phase("      GPU: submit");
    let submitted = gpu.queue.submit([encoder.finish()]);
    #[cfg(target_arch = "wasm32")]
    let _ = submitted; // the browser maps it through its event loop
    drop(submit_phase);
    gpu.count_read_back();
    let state = Arc::new(Mutex::new(MapState::default()));
    let mapped = state.clone();
    staging
        .slice(..(total.max(1) * 4) as u64)
        .map_async(wgpu::MapMode::Read, move |result| {
            let mut state = mapped.lock().unwrap_or_else(|e| e.into_inner());
            state.result = Some(result);
            if let Some(waker) = state.waker.take() {
                waker.wake();
            }
        });
    ReadBack {
        staging: Some(staging),
        total,
        sizes,
        state,
        failed: gpu.failure_slot(),
        adapter: gpu.describe(),
        #[cfg(not(target_arch = "wasm32"))]
        device: gpu.device.clone(),
        #[cfg(not(target_arch = "wasm32"))]
        submitted,
    }
}

#[derive(Default)]
struct MapState {
    result: Option<Result<(), wgpu::BufferAsyncError>>,
    waker: Option<Waker>,
}

/// A submitted copy waiting to be mapped (see [`read_back`]).
pub(crate) struct ReadBack {
    staging: Option<PooledBuffer>,
    total: usize,
    sizes: Vec<usize>,
    state: Arc<Mutex<MapState>>,
    /// The device's failure slot ([`Gpu::failure`]) and its name, for a failed read-back.
    failed: Arc<Mutex<Option<String>>>,
    adapter: String,
    /// Natively, the device to poll and the submission to wait for: the wait comes at the
    /// first poll of the future, so a caller can queue several submissions (a cohort's
    /// networks, `pvrnn_core::train::step_together`) before it waits for the first.
    #[cfg(not(target_arch = "wasm32"))]
    device: wgpu::Device,
    #[cfg(not(target_arch = "wasm32"))]
    submitted: wgpu::SubmissionIndex,
}

impl std::fmt::Debug for ReadBack {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ReadBack")
            .field("floats", &self.total)
            .finish_non_exhaustive()
    }
}

impl ReadBack {
    /// Natively: polls the device until this copy is mapped (also when another thread's
    /// poll mapped it).
    #[cfg(not(target_arch = "wasm32"))]
    fn wait(&self) -> Result<(), String> {
        if self.state.lock().map_or(true, |s| s.result.is_some()) {
            return Ok(());
        }
        let _wait = pvrnn_core::profile::phase("      GPU: wait for the device");
        // This submission only (and those before it), not whatever another thread sharing
        // the device submitted since (the explorer's renderer draws on it).
        let ours = wgpu::PollType::Wait {
            submission_index: Some(self.submitted.clone()),
            timeout: None,
        };
        loop {
            if let Err(e) = self.device.poll(ours.clone()) {
                return Err(format!("waiting for the GPU failed: {e}"));
            }
            if self.state.lock().map_or(true, |s| s.result.is_some()) {
                break;
            }
            // Runs sharing the device (`--jobs N`): another thread's poll took this copy's
            // mapping and is about to call back; ours returned first, with nothing left.
            std::thread::yield_now();
        }
        Ok(())
    }

    /// The device's failure recorded (unless one came first), and zeros in place of the
    /// results (see the module docs).
    fn failed(&mut self, why: String) -> Vec<Vec<f32>> {
        record_failure(&self.failed, format!("{}: {why}", self.adapter));
        if let Some(staging) = self.staging.take() {
            staging.discard();
        }
        self.sizes.iter().map(|&n| vec![0.0; n]).collect()
    }
}

/// A read-back dropped before it was awaited (a caller that gave up on the results) must
/// not put its copy back into the pool mapped, or with its mapping pending.
impl Drop for ReadBack {
    fn drop(&mut self) {
        if let Some(staging) = self.staging.take() {
            staging.discard();
        }
    }
}

impl Future for ReadBack {
    type Output = Vec<Vec<f32>>;

    fn poll(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Self::Output> {
        #[cfg(not(target_arch = "wasm32"))]
        if let Err(why) = self.wait() {
            return Poll::Ready(self.failed(why));
        }
        let result = {
            let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
            match state.result.take() {
                Some(result) => result,
                None => {
                    state.waker = Some(cx.waker().clone());
                    return Poll::Pending;
                }
            }
        };
        if let Err(e) = result {
            return Poll::Ready(self.failed(format!("reading results back failed: {e}")));
        }
        let staging = self.staging.take().expect("a read-back is awaited once");
        let mut out = Vec::with_capacity(self.sizes.len());
        let mapped = match staging
            .slice(..(self.total.max(1) * 4) as u64)
            .get_mapped_range()
        {
            Ok(view) => {
                let all: &[f32] = bytemuck::cast_slice(&view);
                let mut offset = 0;
                for &n in &self.sizes {
                    out.push(all[offset..offset + n].to_vec());
                    offset += n;
                }
                Ok(())
            }
            Err(e) => Err(e.to_string()),
        };
        if let Err(e) = mapped {
            self.staging = Some(staging);
            return Poll::Ready(self.failed(format!("reading results back failed: {e}")));
        }
        // Back to the pool unmapped.
        staging.unmap();
        Poll::Ready(out)
    }
}
