//! The plan as Slurm job arrays: trainings, then inference runs once every training is
//! done, then the report. Each array task runs `pvrnn experiment ... --job K`, which skips
//! a finished job and resumes an interrupted training, so a task hit by the time limit is
//! simply resubmitted (`--signal` gives it time to write its checkpoint).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Result;

use crate::plan::{JobKind, Plan};

/// Options of the emitted scripts.
#[derive(Clone, Debug)]
pub struct SlurmOptions {
    /// The `pvrnn` executable on the cluster.
    pub pvrnn: String,
    /// `--time` of a training task and of an inference task.
    pub train_time: String,
    pub infer_time: String,
    pub cpus: usize,
    /// `--backend` of the tasks and its options: "cpu", "wgpu", "wgpu --gpu-recurrence", ...
    /// (then ask for a GPU with an extra line, for example `--gres=gpu:1`).
    pub backend: String,
    /// Extra `#SBATCH` lines (partition, account).
    pub extra: Vec<String>,
}

fn ranges(ids: &[usize]) -> String {
    let mut out: Vec<String> = Vec::new();
    let mut i = 0;
    while i < ids.len() {
        let mut j = i;
        while j + 1 < ids.len() && ids[j + 1] == ids[j] + 1 {
            j += 1;
        }
        out.push(if i == j {
            ids[i].to_string()
        } else {
            format!("{}-{}", ids[i], ids[j])
        });
        i = j + 1;
    }
    out.join(",")
}

/// Writes `DIR/slurm/{train,infer,report}.sbatch` and `DIR/slurm/submit.sh`; returns the
/// submit script.
pub fn emit(dir: &Path, options: &SlurmOptions) -> Result<PathBuf> {
    let plan = Plan::load(dir)?;
    let dir = std::fs::canonicalize(dir)?;
    let out = dir.join("slurm");
    std::fs::create_dir_all(&out)?;
    let pending = |train: bool| -> Vec<usize> {
        plan.jobs
            .iter()
            .filter(|j| {
                matches!(j.kind, JobKind::Train { .. }) == train && !plan.is_done(&dir, j.id)
            })
            .map(|j| j.id)
            .collect()
    };
    let experiment = plan.experiment.name();
    let scale = plan.scale.name();
    let header = |name: &str, time: &str| {
        let mut s = String::from("#!/bin/bash\n");
        let _ = writeln!(s, "#SBATCH --job-name=pvrnn-{experiment}-{name}");
        let _ = writeln!(s, "#SBATCH --cpus-per-task={}", options.cpus);
        let _ = writeln!(s, "#SBATCH --time={time}");
        let _ = writeln!(s, "#SBATCH --output={}/slurm/%x-%a.out", dir.display());
        // SIGTERM two minutes before the limit: a training writes its checkpoint.
        let _ = writeln!(s, "#SBATCH --signal=B:TERM@120");
        for line in &options.extra {
            let _ = writeln!(s, "#SBATCH {line}");
        }
        s
    };
    let task = |name: &str, time: &str| {
        let mut s = header(name, time);
        let _ = writeln!(
            s,
            "exec {} --threads {} experiment {experiment} --scale {scale} --out {} --job \"$SLURM_ARRAY_TASK_ID\" --backend {}",
            options.pvrnn,
            options.cpus,
            dir.display(),
            options.backend
        );
        s
    };
    pvrnn_core::io::write_atomic(
        &out.join("train.sbatch"),
        task("train", &options.train_time).as_bytes(),
    )?;
    pvrnn_core::io::write_atomic(
        &out.join("infer.sbatch"),
        task("infer", &options.infer_time).as_bytes(),
    )?;
    let mut report = header("report", "00:30:00");
    let _ = writeln!(
        report,
        "exec {} experiment {experiment} --scale {scale} --out {} --report",
        options.pvrnn,
        dir.display()
    );
    pvrnn_core::io::write_atomic(&out.join("report.sbatch"), report.as_bytes())?;
    let (train, infer) = (pending(true), pending(false));
    let mut submit = String::from(
        "#!/bin/bash\n# Submits the jobs of this plan not done yet. Run again after a time limit: finished jobs are skipped, trainings resume.\nset -euo pipefail\ncd \"$(dirname \"$0\")\"\n",
    );
    let _ = writeln!(submit, "dep=\"\"");
    if !train.is_empty() {
        let _ = writeln!(
            submit,
            "train=$(sbatch --parsable --array={} train.sbatch)",
            ranges(&train)
        );
        let _ = writeln!(submit, "dep=\"--dependency=afterok:${{train}}\"");
    }
    if !infer.is_empty() {
        let _ = writeln!(
            submit,
            "infer=$(sbatch --parsable $dep --array={} infer.sbatch)",
            ranges(&infer)
        );
        let _ = writeln!(submit, "dep=\"--dependency=afterok:${{infer}}\"");
    }
    let _ = writeln!(submit, "sbatch $dep report.sbatch");
    let path = out.join("submit.sh");
    pvrnn_core::io::write_atomic(&path, submit.as_bytes())?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755))?;
    }
    Ok(path)
}

#[cfg(test)]
mod tests {
    #[test]
    fn array_ranges_are_compact() {
        assert_eq!(super::ranges(&[0, 1, 2, 5, 7, 8]), "0-2,5,7-8");
        assert_eq!(super::ranges(&[]), "");
    }
}
