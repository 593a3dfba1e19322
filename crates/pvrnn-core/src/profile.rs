//! Where the time of a learning iteration or an inference step goes: wall-clock seconds per
//! named phase, summed while profiling is on (`pvrnn bench --profile`). Off by default; a
//! phase then costs one relaxed atomic load. Native only (wasm has no clock in `std`).

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

static ENABLED: AtomicBool = AtomicBool::new(false);
/// (phase, seconds, times entered), in the order phases were first seen.
static TOTALS: Mutex<Vec<(&'static str, f64, u64)>> = Mutex::new(Vec::new());

/// Turns profiling on or off (and forgets what was summed).
pub fn enable(on: bool) {
    ENABLED.store(on && cfg!(not(target_arch = "wasm32")), Ordering::Relaxed);
    take();
}

/// The sums so far, in the order phases were first entered; resets them.
pub fn take() -> Vec<(&'static str, f64, u64)> {
    std::mem::take(&mut *TOTALS.lock().unwrap_or_else(|e| e.into_inner()))
}

/// Whether profiling is on (for work that costs something to time, such as a device's
/// timestamp queries).
pub fn enabled() -> bool {
    ENABLED.load(Ordering::Relaxed)
}

/// Adds `seconds` measured elsewhere (a device's own clock) to phase `name`, as one entry.
pub fn add(name: &'static str, seconds: f64) {
    if !enabled() {
        return;
    }
    let mut totals = TOTALS.lock().unwrap_or_else(|e| e.into_inner());
    match totals.iter_mut().find(|(n, _, _)| *n == name) {
        Some(entry) => {
            entry.1 += seconds;
            entry.2 += 1;
        }
        None => totals.push((name, seconds, 1)),
    }
}

/// A running phase: its time is added when it is dropped.
#[derive(Debug)]
#[must_use = "a phase is timed until it is dropped"]
pub struct Phase {
    name: &'static str,
    #[cfg(not(target_arch = "wasm32"))]
    start: Option<std::time::Instant>,
}

/// Starts timing `name` (nested phases are counted in both; phases are listed in the order
/// they were first entered, so a phase comes before the phases inside it).
pub fn phase(name: &'static str) -> Phase {
    let on = ENABLED.load(Ordering::Relaxed);
    if on {
        let mut totals = TOTALS.lock().unwrap_or_else(|e| e.into_inner());
        if !totals.iter().any(|(n, _, _)| *n == name) {
            totals.push((name, 0.0, 0));
        }
    }
    Phase {
        name,
        #[cfg(not(target_arch = "wasm32"))]
        start: on.then(std::time::Instant::now),
    }
}

impl Drop for Phase {
    fn drop(&mut self) {
        #[cfg(not(target_arch = "wasm32"))]
        if let Some(start) = self.start {
            let seconds = start.elapsed().as_secs_f64();
            let mut totals = TOTALS.lock().unwrap_or_else(|e| e.into_inner());
            // Absent when profiling was reset while the phase ran.
            if let Some(entry) = totals.iter_mut().find(|(n, _, _)| *n == self.name) {
                entry.1 += seconds;
                entry.2 += 1;
            }
        }
        let _ = self.name;
    }
}
