//! Running a plan's jobs with its report kept current: a part of the design whose analysis
//! runs before the whole plan is done (an interference direction) has its report rebuilt
//! by the run that completes it, without waiting for the rest of the plan. Apart from
//! [`crate::run`], which [`crate::report`] reads results with.

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
/// ([`report::completed_by`]) the report rebuilt and an [`Event::Reported`].
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
    // Jobs finishing together may each find their part complete: one report per part.
    let reported = Mutex::new(BTreeSet::new());
    let reporting = |e: Event<'_>| {
        let finished = match &e {
            Event::Finished { id, .. } => Some(*id),
            _ => None,
        };
        events(e);
        if let Some(id) = finished
            && let Some(part) = report::completed_by(&plan, dir, id)
            && reported
                .lock()
                .is_ok_and(|mut parts| parts.insert(part.clone()))
        {
            let written = report::write(dir)
                .map(|d| d.join("report.md"))
                .map_err(|e| format!("{e:#}"));
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
