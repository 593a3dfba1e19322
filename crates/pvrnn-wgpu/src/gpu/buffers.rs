//! The device's buffers: uploads, scratch, uniforms and read-back staging from the pool, and
//! long-lived buffers filled without mapping.

use crate::pool::PooledBuffer;

use super::Gpu;

impl Gpu {
    /// A storage buffer holding `data` (written at the next submission), from the pool:
    /// f32 values, or 32-bit words (tables of shapes and offsets).
    pub(crate) fn upload<P: bytemuck::Pod>(&self, label: &str, data: &[P]) -> PooledBuffer {
        let words = std::mem::size_of_val(data).div_ceil(4);
        let buffer = self.scratch(label, words, wgpu::BufferUsages::empty());
        if !data.is_empty() {
            self.queue
                .write_buffer(&buffer, 0, bytemuck::cast_slice(data));
        }
        buffer
    }

    /// A long-lived buffer (not pooled) holding `data`, written at the next submission.
    /// Not `create_buffer_init`: when the device is out of memory that maps an invalid
    /// buffer and panics inside wgpu, where this leaves an error for [`Gpu::allocating`]'s
    /// scope to report.
    pub(crate) fn filled<P: bytemuck::Pod>(
        &self,
        label: &str,
        data: &[P],
        usage: wgpu::BufferUsages,
    ) -> wgpu::Buffer {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: (bytes.len() as u64).next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT),
            usage: usage | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        if !bytes.is_empty() {
            self.queue.write_buffer(&buffer, 0, bytes);
        }
        buffer
    }

    /// A storage buffer of `floats` values whose contents are undefined (the pool's last
    /// user's): for results the kernels write before anything reads them.
    pub(crate) fn scratch(
        &self,
        label: &str,
        floats: usize,
        extra: wgpu::BufferUsages,
    ) -> PooledBuffer {
        self.pool.take(
            &self.device,
            label,
            4 * floats as u64,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | extra,
        )
    }

    /// A uniform buffer holding `params`.
    pub(crate) fn uniform<P: bytemuck::Pod>(&self, params: &P) -> PooledBuffer {
        let bytes = bytemuck::bytes_of(params);
        let buffer = self.pool.take(
            &self.device,
            "params",
            bytes.len() as u64,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        );
        self.queue.write_buffer(&buffer, 0, bytes);
        buffer
    }

    /// A mappable buffer of `floats` values for reading results back.
    pub(crate) fn staging(&self, floats: usize) -> PooledBuffer {
        self.pool.take(
            &self.device,
            "read back",
            4 * floats as u64,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        )
    }
}
