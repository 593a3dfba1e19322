//! Running a plan's jobs with its report kept current: a part of the design whose analysis
//! runs before the whole plan is done (an interference direction) has its report rebuilt
//! by the run that completes it, without waiting for the rest of the plan; so has each
//! network once its training and inference runs are done (a campaign of 40 trainings runs
//! for days). Apart from [`crate::run`], which [`crate::report`] reads results with.

use std::collections::BTreeSet;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};

use anyhow::Result;
use pvrnn_core::backend::Backend;

use crate::plan::Plan;
use crate::report;
use crate::run::{self, Event, Selection, Workers};

/// [`run::run_with`], and after each finished job that completes a part of the design
/// ([`report::completed_by`]) or a network ([`report::network_completed_by`]) the report
/// rebuilt and an [`Event::Reported`] naming what was completed.
pub fn run_with(
    dir: &Path,
    backend: &Arc<dyn Backend<f32>>,
    backend_name: &str,
    workers: Workers,
    selection: Selection,
    stop: &AtomicBool,
    events: &(dyn Fn(Event<'_>) + Sync),
) -> Result<()> {
    let plan = Plan::load(dir)?;
    // Jobs finishing together may each find their part complete: one report per part (or
    // network), written by one thread at a time.
    let reported = Mutex::new(BTreeSet::new());
    let reporting = |e: Event<'_>| {
        let finished = match &e {
            Event::Finished { id, .. } => Some(*id),
            _ => None,
        };
        events(e);
        // A direction's completion names it; otherwise a network's, if this finished it.
        if let Some(id) = finished
            && let Some(part) = report::completed_by(&plan, dir, id)
                .or_else(|| report::network_completed_by(&plan, dir, id))
            && let Ok(mut parts) = reported.lock()
            && parts.insert(part.clone())
        {
            let written = report::write(dir)
                .map(|d| d.join("report.md"))
                .map_err(|e| format!("{e:#}"));
            drop(parts);
            events(Event::Reported {
                id,
                part: &part,
                report: written.as_deref().map_err(String::as_str),
            });
        }
    };
    run::run_with(
        dir,
        backend,
        backend_name,
        workers,
        selection,
        stop,
        &reporting,
    )
}
