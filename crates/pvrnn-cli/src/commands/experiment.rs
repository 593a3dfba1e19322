//! `pvrnn experiment`: plan, run (resumably, in parallel, or one job for a cluster) and
//! report one of the paper's experiments.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use pvrnn_experiment::run::{Event, Interrupted, Selection};
use pvrnn_experiment::slurm::SlurmOptions;
use pvrnn_experiment::{Experiment, Plan, Scale, report};

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example:\n  pvrnn experiment robustness --scale smoke --dataset data/caresim --out runs/robustness-smoke\n  pvrnn experiment robustness --scale smoke --out runs/robustness-smoke --network 0\n  pvrnn experiment robustness --out runs/robustness-smoke --report   # the plan's scale"
)]
pub struct Args {
    /// hierarchy (Figs 2-3), uncertainty (Fig 4), robustness (Fig 5) or interference (Fig 6).
    #[arg(value_parser = ["hierarchy", "uncertainty", "robustness", "interference"])]
    experiment: String,
    /// smoke (minutes; tests the machinery), reduced (3 networks, fixed iterations: about
    /// 12 h of 2-core training), converged (5 networks, each trained until it converges;
    /// needs --validate) or paper (5 networks x 100,000 iterations, 5 trials). Default:
    /// the plan's own scale when --out has one, else smoke.
    #[arg(long, value_parser = ["smoke", "reduced", "converged", "paper"])]
    scale: Option<String>,
    /// The experiment's folder: plan.json, networks/, results/, report/.
    #[arg(long)]
    out: PathBuf,
    /// The caresim dataset folder (`pvrnn simulate`); needed to create the plan.
    #[arg(long)]
    dataset: Option<PathBuf>,
    /// Jobs run at once (each uses the --threads pool).
    #[arg(long, default_value_t = 1)]
    jobs: usize,
    /// Train up to this many networks of one condition (the same sequences, other seeds)
    /// together in one job slot: on a GPU with `--gpu-recurrence` every iteration of all of
    /// them is queued before the host waits for any, instead of processes competing for
    /// the device. Each network's result is the one it gets alone. Not with --network
    /// (a network's jobs are all of other conditions).
    #[arg(long, default_value_t = 1, conflicts_with = "network",
          value_parser = clap::value_parser!(u32).range(1..=64))]
    cohort: u32,
    /// Run only this job of the plan (a cluster array task); its dependencies must be done.
    #[arg(long, conflicts_with_all = ["report", "emit"])]
    job: Option<usize>,
    /// Run only this network's jobs (each training, then its inference runs), then write the
    /// report of what is done: networks finish one by one, so a run split across sessions or
    /// machines gives complete networks early.
    #[arg(long, conflicts_with_all = ["job", "report", "emit"])]
    network: Option<usize>,
    /// Only rebuild the report from the results there are.
    #[arg(long, conflicts_with = "emit")]
    report: bool,
    /// Write cluster scripts for the jobs not done yet instead of running them.
    #[arg(long, value_parser = ["slurm"])]
    emit: Option<String>,
    /// A trained checkpoint to use as network 0 instead of training it: same seed (0), data
    /// and iterations (reduced scale: a 10,000-iteration checkpoint of `pvrnn train` on
    /// all 18 learning sequences).
    #[arg(long)]
    reuse: Option<PathBuf>,
    /// The held-out dataset of the convergence rule (converged scale; e.g. `pvrnn simulate
    /// --seed 1`): each network is validated on it every 2,000 iterations.
    #[arg(long)]
    validate: Option<PathBuf>,
    /// A folder for the trained networks shared by experiments at the same scale
    /// (hierarchy, uncertainty and robustness train the same networks; default DIR/networks).
    #[arg(long)]
    networks: Option<PathBuf>,
    /// Slurm: the `pvrnn` executable on the cluster.
    #[arg(long, default_value = "pvrnn")]
    slurm_pvrnn: String,
    /// Slurm: time limit of a training task (HH:MM:SS); a training stopped by it (SIGTERM)
    /// writes its checkpoint, and submitting the script again resumes it.
    #[arg(long, default_value = "24:00:00")]
    slurm_train_time: String,
    /// Slurm: time limit of an inference task (HH:MM:SS).
    #[arg(long, default_value = "02:00:00")]
    slurm_infer_time: String,
    /// Slurm: CPUs per task.
    #[arg(long, default_value_t = 4)]
    slurm_cpus: usize,
    /// Slurm: extra `#SBATCH` options, e.g. `--partition=cpu` (repeatable).
    #[arg(long)]
    slurm_option: Vec<String>,
    #[command(flatten)]
    backend: crate::util::BackendArgs,
}

pub fn run(a: Args) -> Result<()> {
    let experiment = Experiment::parse(&a.experiment).expect("clap checks the name");
    let asked = a
        .scale
        .as_deref()
        .map(|s| Scale::parse(s).expect("clap checks the scale"));
    let plan = if Plan::path(&a.out).is_file() {
        let plan = Plan::load(&a.out)?;
        plan.check_matches(experiment, asked.unwrap_or(plan.scale))?;
        if a.reuse.is_some() || a.networks.is_some() || a.validate.is_some() {
            bail!(
                "--reuse, --networks and --validate apply when the plan is created; {} already has one",
                a.out.display()
            );
        }
        plan
    } else {
        let Some(dataset) = &a.dataset else {
            bail!(
                "{} has no plan yet: pass --dataset (a caresim folder from `pvrnn simulate`) to create it",
                a.out.display()
            );
        };
        let mut plan = Plan::new(
            experiment,
            asked.unwrap_or(Scale::Smoke),
            dataset,
            a.reuse.as_deref(),
            a.validate.as_deref(),
        )?;
        if let Some(dir) = &a.networks {
            plan.claim_networks_dir(dir)?;
        }
        plan.save(&a.out)?;
        eprintln!(
            "planned {} at {} scale: {} jobs, about {:.1} h of 2-core training ({})",
            experiment.name(),
            plan.scale.name(),
            plan.jobs.len(),
            plan.design.estimated_training_hours,
            Plan::path(&a.out).display()
        );
        plan
    };
    if a.emit.is_some() {
        let script = pvrnn_experiment::slurm::emit(
            &a.out,
            &SlurmOptions {
                pvrnn: a.slurm_pvrnn,
                train_time: a.slurm_train_time,
                infer_time: a.slurm_infer_time,
                cpus: a.slurm_cpus,
                backend: a.backend.flags(),
                extra: a.slurm_option,
            },
        )?;
        eprintln!(
            "wrote {}; submit with `bash {}`",
            script.display(),
            script.display()
        );
        return Ok(());
    }
    if !a.report {
        run_jobs(&a, &plan)?;
        if a.job.is_some() {
            return Ok(());
        }
    }
    let dir = report::write(&a.out)?;
    eprintln!("report: {}", dir.join("report.md").display());
    Ok(())
}

/// Runs the selected jobs of `plan` with a progress bar (a line per event when stderr is
/// not a terminal); exits with 130 when interrupted, its checkpoints written.
fn run_jobs(a: &Args, plan: &Plan) -> Result<()> {
    let (backend, backend_name) = a.backend.open()?;
    let backend: Arc<dyn pvrnn_core::backend::Backend<f32>> = Arc::from(backend);
    if a.backend.backend != crate::util::BackendKind::Cpu {
        eprintln!("backend: {backend_name}");
    }
    // Recorded in every result: times and f32 rounding depend on it.
    let computed_by = format!(
        "{backend_name}, {} threads{}",
        rayon::current_num_threads(),
        if a.jobs > 1 {
            format!(" shared by {} jobs at once", a.jobs)
        } else {
            String::new()
        },
    ) + &if a.cohort > 1 {
        format!(", trained in cohorts of up to {}", a.cohort)
    } else {
        String::new()
    };
    let stop = Arc::new(AtomicBool::new(false));
    {
        let flag = stop.clone();
        ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst))
            .context("cannot install the Ctrl-C / SIGTERM handler")?;
    }
    let selection = match (a.job, a.network) {
        (Some(id), _) => Selection::Job(id),
        (None, Some(k)) => Selection::Network(k),
        (None, None) => Selection::All,
    };
    let selected = selection.jobs(plan);
    let total = selected.len();
    let done_before = selected
        .iter()
        .filter(|&&i| plan.is_done(&a.out, i))
        .count();
    let bar = crate::util::progress(total as u64, "jobs");
    bar.set_position(done_before as u64);
    let tty = std::io::stderr().is_terminal();
    let last_line = std::sync::Mutex::new(Instant::now());
    // A line of its own: above the progress bar on a terminal, else to stderr.
    let say = |line: String| {
        if tty {
            bar.println(line)
        } else {
            eprintln!("{line}")
        }
    };
    let events = |e: Event<'_>| match e {
        Event::Started { id, name } => {
            if !tty {
                eprintln!("job {id} ({name}) started");
            }
        }
        Event::Finished { id, name, seconds } => {
            bar.inc(1);
            say(format!("job {id} ({name}) done in {seconds:.1} s"));
        }
        Event::Reported { part, report, .. } => {
            say(match report {
                Ok(path) => format!("{part} is complete: report {}", path.display()),
                Err(why) => format!(
                    "{part} is complete, but its report failed: {why} (run again with --report)"
                ),
            });
        }
        Event::Training {
            id,
            done,
            total,
            free_energy,
        } => {
            bar.set_message(format!(
                "job {id}: iteration {done}/{total}, F {free_energy:.4}"
            ));
            if let Ok(mut t) = last_line.lock()
                && !tty
                && t.elapsed().as_secs() >= 30
            {
                *t = Instant::now();
                eprintln!("job {id}: iteration {done}/{total}, F {free_energy:.4}");
            }
        }
        Event::Inferring { id, done, total } => {
            bar.set_message(format!("job {id}: step {done}/{total}"));
        }
        Event::Diverged { id, name, step } => {
            say(format!(
                "job {id} ({name}): online inference diverged beyond repair at step {step}; recorded, the report leaves it out"
            ));
        }
    };
    let workers = pvrnn_experiment::run::Workers {
        jobs: a.jobs,
        cohort: a.cohort as usize,
    };
    let result = pvrnn_experiment::reporting::run_with(
        &a.out,
        &backend,
        &computed_by,
        workers,
        selection,
        &stop,
        &events,
    );
    bar.finish_and_clear();
    if let Err(e) = result {
        if e.downcast_ref::<Interrupted>().is_some() {
            eprintln!("interrupted: checkpoints written; run the same command again to resume");
            std::process::exit(130);
        }
        return Err(e);
    }
    Ok(())
}
