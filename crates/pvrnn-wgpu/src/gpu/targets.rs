//! Targets kept on the device between calls ([`ResidentTargets`]), for every run that used
//! them lately, keyed by their observations and cut ([`ResidentKey`]).

use std::sync::Arc;

/// Learning targets kept on the device: which observations, and how they were cut.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct ResidentKey {
    pub(crate) observations: u64,
    pub(crate) rows: usize,
    pub(crate) columns: usize,
    pub(crate) chunk_rows: usize,
}

/// Targets kept on the device, for every run that used them lately: several trainings or
/// inference runs may share one GPU (`pvrnn experiment --jobs N --backend wgpu`), and one
/// slot per modality would re-upload each run's targets whenever another ran in between.
#[derive(Debug, Default)]
pub(crate) struct ResidentTargets {
    entries: Vec<ResidentEntry>,
    /// Look-ups so far: the clock that says which entries are stale.
    clock: u64,
    pub(super) uploads: u64,
}

#[derive(Debug)]
struct ResidentEntry {
    modality: usize,
    key: ResidentKey,
    chunks: Arc<Vec<wgpu::Buffer>>,
    /// The look-up clock and the time at its last use.
    last_used: u64,
    last_used_at: web_time::Instant,
}

impl ResidentTargets {
    /// An entry is freed once unused both for this many look-ups (of any run) and for
    /// [`Self::STALE_AFTER`]: a run that ended, an inference step's window a second after
    /// its step. Both, because look-ups alone would let a fast run (an online inference
    /// looks up about 2 x 50 times per step) evict a slow one's data between its
    /// iterations, and time alone would drop a lone slow run's data (a learning
    /// iteration on a CPU adapter takes seconds) when nothing else needs the room.
    const STALE_AFTER_LOOKUPS: u64 = 64;
    const STALE_AFTER: std::time::Duration = std::time::Duration::from_secs(1);
    /// At most this many entries (a run has one per modality on the GPU) stay, the least
    /// recently used going first.
    const MAX_ENTRIES: usize = 64;

    /// The targets under `key`, made by `upload` if they are not on the device.
    pub(crate) fn get_or_upload(
        &mut self,
        modality: usize,
        key: ResidentKey,
        upload: impl FnOnce() -> Vec<wgpu::Buffer>,
    ) -> Arc<Vec<wgpu::Buffer>> {
        self.clock += 1;
        let (now, now_at) = (self.clock, web_time::Instant::now());
        self.entries.retain(|e| {
            now - e.last_used <= Self::STALE_AFTER_LOOKUPS
                || now_at.duration_since(e.last_used_at) <= Self::STALE_AFTER
        });
        if let Some(e) = self
            .entries
            .iter_mut()
            .find(|e| e.modality == modality && e.key == key)
        {
            e.last_used = now;
            e.last_used_at = now_at;
            return e.chunks.clone();
        }
        while self.entries.len() >= Self::MAX_ENTRIES {
            let oldest = (0..self.entries.len())
                .min_by_key(|&i| self.entries[i].last_used)
                .unwrap_or(0);
            self.entries.swap_remove(oldest);
        }
        self.uploads += 1;
        let chunks = Arc::new(upload());
        self.entries.push(ResidentEntry {
            modality,
            key,
            chunks: chunks.clone(),
            last_used: now,
            last_used_at: now_at,
        });
        chunks
    }
}
