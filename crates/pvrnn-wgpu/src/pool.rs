//! Reused device buffers. Learning allocates the same buffers every iteration and online
//! inference every update (50 per step); creating, zero-filling and freeing them each time
//! cost more than the kernels at inference's small shapes. A [`PooledBuffer`] goes back to
//! the pool when dropped, and the next request of the same size and usage takes it again,
//! with its old contents: every user writes what it later reads.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

/// Buffers kept per (size, usage) once returned, at most: enough for a submission that
/// holds many of one size (a cohort's members, the chunks of an output layer) to find them
/// all again at its next call. Of large buffers fewer: at most [`KEEP_BYTES_PER_KEY`] in
/// all, and always [`KEEP_AT_LEAST`]. More are freed.
const KEEP_PER_KEY: usize = 64;
const KEEP_BYTES_PER_KEY: u64 = 64 << 20;
const KEEP_AT_LEAST: usize = 4;

type Key = (u64, u32);

#[derive(Debug, Default)]
pub(crate) struct BufferPool {
    free: Mutex<HashMap<Key, Vec<wgpu::Buffer>>>,
}

impl BufferPool {
    /// A buffer of `bytes` (at least 4) with `usage`, reused when one is free.
    pub(crate) fn take(
        self: &Arc<Self>,
        device: &wgpu::Device,
        label: &str,
        bytes: u64,
        usage: wgpu::BufferUsages,
    ) -> PooledBuffer {
        let bytes = bytes.max(4).next_multiple_of(4);
        let key = (bytes, usage.bits());
        let reused = self
            .free
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get_mut(&key)
            .and_then(Vec::pop);
        let buffer = reused.unwrap_or_else(|| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes,
                usage,
                mapped_at_creation: false,
            })
        });
        PooledBuffer {
            buffer: Some(buffer),
            pool: self.clone(),
        }
    }

    fn give(&self, buffer: wgpu::Buffer) {
        let key = (buffer.size(), buffer.usage().bits());
        let mut free = self.free.lock().unwrap_or_else(|e| e.into_inner());
        let list = free.entry(key).or_default();
        let keep =
            ((KEEP_BYTES_PER_KEY / key.0.max(1)) as usize).clamp(KEEP_AT_LEAST, KEEP_PER_KEY);
        if list.len() < keep {
            list.push(buffer);
        }
    }
}

/// A buffer that returns to its pool when dropped.
#[derive(Debug)]
pub(crate) struct PooledBuffer {
    buffer: Option<wgpu::Buffer>,
    pool: Arc<BufferPool>,
}

impl std::ops::Deref for PooledBuffer {
    type Target = wgpu::Buffer;

    fn deref(&self) -> &wgpu::Buffer {
        self.buffer.as_ref().expect("present until dropped")
    }
}

impl PooledBuffer {
    /// Frees the buffer instead of returning it to the pool (a read-back's copy dropped
    /// while mapped, or while its mapping is pending, must not be handed out again).
    pub(crate) fn discard(mut self) {
        if let Some(buffer) = self.buffer.take() {
            buffer.destroy();
        }
    }
}

impl Drop for PooledBuffer {
    fn drop(&mut self) {
        if let Some(buffer) = self.buffer.take() {
            self.pool.give(buffer);
        }
    }
}
