//! Shared helpers: thread pool, configuration files, progress bars.

use std::path::Path;
use std::sync::{Arc, Mutex, mpsc};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use pvrnn_core::ModelConfig;

pub fn set_threads(threads: Option<usize>) -> Result<()> {
    if let Some(n) = threads {
        anyhow::ensure!(n >= 1, "--threads must be at least 1");
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .context("could not start the thread pool")?;
    }
    Ok(())
}

/// Reads a TOML configuration. Fields it leaves out keep the paper's defaults, at any depth
/// (so `[executive]\nd = 20` changes only d); unknown fields are errors.
pub fn load_config(path: Option<&Path>) -> Result<ModelConfig> {
    let Some(path) = path else {
        return Ok(ModelConfig::default());
    };
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("{}: cannot read", path.display()))?;
    let user: toml::Value =
        toml::from_str(&text).with_context(|| format!("{}: not valid TOML", path.display()))?;
    let mut merged =
        toml::Value::try_from(ModelConfig::default()).expect("default config serialises");
    merge(&mut merged, user);
    let config: ModelConfig = merged
        .try_into()
        .with_context(|| format!("{}: not a valid pvrnn configuration", path.display()))?;
    config
        .validate()
        .with_context(|| format!("{}", path.display()))?;
    Ok(config)
}

fn merge(base: &mut toml::Value, over: toml::Value) {
    match (base, over) {
        (toml::Value::Table(b), toml::Value::Table(o)) => {
            for (k, v) in o {
                match b.get_mut(&k) {
                    Some(slot) => merge(slot, v),
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (slot, v) => *slot = v,
    }
}

pub fn config_to_toml(config: &ModelConfig) -> String {
    toml::to_string_pretty(config).expect("configuration serialises to TOML")
}

/// Progress of a long job on stderr: a bar on a terminal; otherwise (`nohup`, a cluster
/// job's log) a plain line at a steady interval: done/total, the last message (e.g. the free
/// energy), seconds per unit and the time left. The interval is 60 s, or
/// `PVRNN_PROGRESS_EVERY` seconds.
#[derive(Debug)]
pub struct Progress {
    bar: ProgressBar,
    plain: Option<Arc<Mutex<Plain>>>,
    /// Dropped with the progress: stops the thread that prints the plain line on time even
    /// while one unit of work takes longer than the interval.
    _ticker: Option<mpsc::Sender<()>>,
}

#[derive(Debug)]
struct Plain {
    what: String,
    len: u64,
    pos: u64,
    message: String,
    start: std::time::Instant,
    /// Position and time at the start, so a resumed run's rate counts only this run.
    first_pos: Option<u64>,
    last_print: Option<std::time::Instant>,
    every: Duration,
    /// Finished or abandoned: the last line is out, the ticker says nothing more.
    ended: bool,
}

impl Plain {
    /// Prints the line when the interval has passed since the last one (or `force`).
    fn report(&mut self, force: bool) {
        let due = self.last_print.is_none_or(|t| t.elapsed() >= self.every);
        if force || (due && !self.ended) {
            eprintln!("{}", self.line());
            self.last_print = Some(std::time::Instant::now());
        }
    }

    fn line(&self) -> String {
        let elapsed = self.start.elapsed().as_secs_f64();
        let done = self.pos.saturating_sub(self.first_pos.unwrap_or(0));
        let mut out = format!("{}: {}/{}", self.what, self.pos, self.len);
        if self.len > 0 {
            out.push_str(&format!(
                " ({:.1}%)",
                100.0 * self.pos as f64 / self.len as f64
            ));
        }
        if !self.message.is_empty() {
            out.push_str(&format!(", {}", self.message));
        }
        if done > 0 {
            let per = elapsed / done as f64;
            out.push_str(&format!(", {per:.3} s each"));
            if self.len > self.pos {
                out.push_str(&format!(
                    ", ETA {}",
                    duration_text(per * (self.len - self.pos) as f64)
                ));
            }
        }
        out
    }
}

/// `2h 05m`, `3m 20s`, `12s`.
pub fn duration_text(seconds: f64) -> String {
    let s = seconds.max(0.0).round() as u64;
    match (s / 3600, (s % 3600) / 60, s % 60) {
        (0, 0, sec) => format!("{sec}s"),
        (0, m, sec) => format!("{m}m {sec:02}s"),
        (h, m, _) => format!("{h}h {m:02}m"),
    }
}

impl Progress {
    fn with_plain(&self, f: impl FnOnce(&mut Plain)) {
        if let Some(plain) = &self.plain
            && let Ok(mut p) = plain.lock()
        {
            f(&mut p);
        }
    }

    /// Prints the plain line when the interval has passed (or `force`).
    fn report(&self, force: bool) {
        self.with_plain(|p| p.report(force));
    }

    pub fn set_position(&self, pos: u64) {
        self.bar.set_position(pos);
        self.with_plain(|p| {
            p.first_pos.get_or_insert(pos);
            p.pos = pos;
        });
        self.report(false);
    }

    pub fn inc(&self, n: u64) {
        self.bar.inc(n);
        self.with_plain(|p| {
            p.first_pos.get_or_insert(p.pos);
            p.pos += n;
        });
        self.report(false);
    }

    pub fn set_length(&self, len: u64) {
        self.bar.set_length(len);
        self.with_plain(|p| p.len = len);
    }

    pub fn set_message(&self, message: String) {
        self.with_plain(|p| p.message.clone_from(&message));
        self.bar.set_message(message);
    }

    pub fn println(&self, line: impl AsRef<str>) {
        if self.plain.is_some() {
            eprintln!("{}", line.as_ref());
        } else {
            self.bar.println(line);
        }
    }

    pub fn finish(&self) {
        self.bar.finish();
        self.end();
    }

    pub fn finish_and_clear(&self) {
        self.bar.finish_and_clear();
        self.end();
    }

    pub fn abandon(&self) {
        self.bar.abandon();
        self.end();
    }

    /// The last plain line.
    fn end(&self) {
        self.with_plain(|p| {
            p.report(true);
            p.ended = true;
        });
    }
}

/// Progress of `len` units of `what` on stderr (see [`Progress`]).
pub fn progress(len: u64, what: &str) -> Progress {
    use std::io::IsTerminal;
    if std::io::stderr().is_terminal() {
        let bar = ProgressBar::new(len);
        bar.set_style(
            ProgressStyle::with_template(&format!(
                "{what} {{bar:30}} {{pos}}/{{len}} [{{elapsed_precise}} < {{eta_precise}}] {{msg}}"
            ))
            .expect("valid template"),
        );
        bar.enable_steady_tick(Duration::from_millis(200));
        return Progress {
            bar,
            plain: None,
            _ticker: None,
        };
    }
    let every = std::env::var("PVRNN_PROGRESS_EVERY")
        .ok()
        .and_then(|v| v.parse::<f64>().ok())
        .filter(|v| v.is_finite() && *v >= 0.0)
        .unwrap_or(60.0);
    let every = Duration::from_secs_f64(every);
    let plain = Arc::new(Mutex::new(Plain {
        what: what.to_string(),
        len,
        pos: 0,
        message: String::new(),
        start: std::time::Instant::now(),
        first_pos: None,
        last_print: Some(std::time::Instant::now()),
        every,
        ended: false,
    }));
    // With an interval of 0 every update prints; otherwise a thread keeps the lines coming
    // at the interval while the work is between updates (a slow iteration or sequence).
    let ticker = (!every.is_zero()).then(|| {
        let (stop, stopped) = mpsc::channel::<()>();
        let plain = plain.clone();
        std::thread::spawn(move || {
            while let Err(mpsc::RecvTimeoutError::Timeout) = stopped.recv_timeout(every) {
                if let Ok(mut p) = plain.lock() {
                    p.report(false);
                }
            }
        });
        stop
    });
    Progress {
        bar: ProgressBar::hidden(),
        plain: Some(plain),
        _ticker: ticker,
    }
}

/// Parses `on`/`off`.
pub fn on_off(s: &str) -> Result<bool, String> {
    match s {
        "on" | "true" | "yes" => Ok(true),
        "off" | "false" | "no" => Ok(false),
        _ => Err(format!("expected on or off, got `{s}`")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn partial_toml_overrides_only_what_it_names() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.toml");
        std::fs::write(
            &p,
            "kl_weight = 0.01\n[executive]\nd = 20\n[inference]\nwindow = 10\n",
        )
        .unwrap();
        let c = load_config(Some(&p)).unwrap();
        assert_eq!(c.kl_weight, 0.01);
        assert_eq!(c.executive.d, 20);
        assert_eq!(c.executive.z, 30);
        assert_eq!(c.inference.window, 10);
        assert_eq!(c.inference.iterations, 50);
        std::fs::write(&p, "[executive]\nsize = 20\n").unwrap();
        let e = format!("{:#}", load_config(Some(&p)).unwrap_err());
        assert!(e.contains("size"), "{e}");
        std::fs::write(&p, "[executive]\ntau = [0.5, 2.0]\n").unwrap();
        let e = format!("{:#}", load_config(Some(&p)).unwrap_err());
        assert!(e.contains("executive.tau"), "{e}");
    }

    #[test]
    fn plain_progress_lines_say_rate_and_time_left() {
        let p = Plain {
            what: "train".into(),
            len: 1000,
            pos: 400,
            message: "F 16.5".into(),
            start: std::time::Instant::now() - Duration::from_secs(100),
            first_pos: Some(200),
            last_print: None,
            every: Duration::ZERO,
            ended: false,
        };
        // 200 iterations in 100 s: 0.5 s each, 600 left: 5 minutes.
        assert_eq!(
            p.line(),
            "train: 400/1000 (40.0%), F 16.5, 0.500 s each, ETA 5m 00s"
        );
        assert_eq!(duration_text(7530.0), "2h 05m");
        assert_eq!(duration_text(12.4), "12s");
    }

    #[test]
    fn default_config_round_trips_through_toml() {
        let text = config_to_toml(&ModelConfig::default());
        let back: ModelConfig = toml::from_str(&text).unwrap();
        assert_eq!(back, ModelConfig::default());
    }
}

/// `--backend`: where the model's arithmetic runs.
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct BackendArgs {
    /// Where the arithmetic runs: `cpu`, or `wgpu` (a GPU through Vulkan, Metal or DX12; today
    /// the read-outs' output layers, about 97% of a learning iteration's arithmetic, run there
    /// and the recurrence stays on the CPU unless `--gpu-recurrence`). `WGPU_ADAPTER_NAME`
    /// picks an adapter.
    #[arg(long, value_enum, default_value_t = BackendKind::Cpu)]
    pub backend: BackendKind,
    /// With `--backend wgpu`, for learning: run the recurrence (forward, back-propagation
    /// through time, its weight gradients) on the GPU too, one workgroup per window. Unless
    /// `--weights-on-host` the whole iteration then stays on the GPU: the recurrent weights
    /// and the adaptive variables with their optimiser state too, one submission per
    /// iteration, only the free-energy terms read back (on an H200 0.0256 against 0.0299 s
    /// per paper-scale iteration). Online inference keeps the recurrence on the CPU (`infer`
    /// and `evaluate` refuse this flag; an experiment's inference runs leave it out): there
    /// the GPU's made it slower (21 against 35 steps/s with 16x16 + proprioception;
    /// docs/gpu.md).
    #[arg(long)]
    pub gpu_recurrence: bool,
    /// With `--backend wgpu`: upload the weights and read their gradients back every
    /// learning iteration, updating them on the CPU, instead of keeping the output layers'
    /// weights and optimiser state on the GPU for the whole run (the default). For
    /// comparing the two on one machine; results agree to f32 rounding.
    #[arg(long)]
    pub weights_on_host: bool,
    /// With `--backend wgpu`: which kernels keep wgpu's runtime checks (bounds, loop
    /// bounding, division). `audited`: every kernel but the output layers' five main ones,
    /// whose indices are audited and whose checks cost them a fourth of their time on an
    /// H200; `all`: every kernel, to rule the unchecked ones out when a result looks wrong;
    /// `none`: no kernel, to measure what the checks cost (docs/gpu.md).
    #[arg(long, value_enum, default_value_t = ChecksArg::Audited)]
    pub wgpu_checks: ChecksArg,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum BackendKind {
    Cpu,
    Wgpu,
}

/// `--wgpu-checks`: [`pvrnn_wgpu::RuntimeChecks`] on the command line.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum ChecksArg {
    Audited,
    All,
    None,
}

impl ChecksArg {
    fn checks(self) -> pvrnn_wgpu::RuntimeChecks {
        match self {
            Self::Audited => pvrnn_wgpu::RuntimeChecks::Audited,
            Self::All => pvrnn_wgpu::RuntimeChecks::All,
            Self::None => pvrnn_wgpu::RuntimeChecks::None,
        }
    }

    fn name(self) -> &'static str {
        match self {
            Self::Audited => "audited",
            Self::All => "all",
            Self::None => "none",
        }
    }
}

/// A backend, what it runs on in words, and its GPU device if it has one.
pub type OpenedBackend = (
    Box<dyn pvrnn_core::backend::Backend<f32>>,
    String,
    Option<std::sync::Arc<pvrnn_wgpu::Gpu>>,
);

impl BackendArgs {
    /// `--backend`'s value and options as written on a command line ("wgpu
    /// --gpu-recurrence"), for the commands a Slurm script runs.
    pub fn flags(&self) -> String {
        let mut flags = match self.backend {
            BackendKind::Cpu => "cpu".to_string(),
            BackendKind::Wgpu => "wgpu".to_string(),
        };
        if self.gpu_recurrence {
            flags.push_str(" --gpu-recurrence");
        }
        if self.weights_on_host {
            flags.push_str(" --weights-on-host");
        }
        if self.wgpu_checks != ChecksArg::Audited {
            flags.push_str(" --wgpu-checks ");
            flags.push_str(self.wgpu_checks.name());
        }
        flags
    }

    /// The wgpu backend's options these flags choose.
    pub fn wgpu_options(&self) -> pvrnn_wgpu::WgpuOptions {
        pvrnn_wgpu::WgpuOptions {
            recurrence_on_gpu: self.gpu_recurrence,
            weights_on_host: self.weights_on_host,
            checks: self.wgpu_checks.checks(),
            profile_kernels: false,
        }
    }

    /// [`Self::open`] for a command that only runs online inference (`infer`, `evaluate`),
    /// which refuses `--gpu-recurrence`: a learning option, since online inference keeps
    /// the recurrence on the CPU whatever it says.
    pub fn open_for_inference(
        &self,
        command: &str,
    ) -> Result<(Box<dyn pvrnn_core::backend::Backend<f32>>, String)> {
        if self.gpu_recurrence {
            bail!(
                "--gpu-recurrence is a learning option and `pvrnn {command}` runs online \
                 inference, which keeps the recurrence on the CPU (on an H200 the GPU's \
                 recurrence made it slower: docs/gpu.md); leave it out"
            );
        }
        self.open()
    }

    /// Opens the backend and says in words what it runs on ("cpu" or the GPU adapter).
    pub fn open(&self) -> Result<(Box<dyn pvrnn_core::backend::Backend<f32>>, String)> {
        self.open_with_gpu()
            .map(|(backend, name, _)| (backend, name))
    }

    /// [`Self::open`], with the GPU device when the backend has one (for its memory
    /// figures).
    pub fn open_with_gpu(&self) -> Result<OpenedBackend> {
        self.open_with(self.wgpu_options())
    }

    /// [`Self::open_with_gpu`] with the wgpu backend's `options` ([`Self::wgpu_options`]
    /// and what a command adds: `bench --profile-kernels`).
    pub fn open_with(&self, options: pvrnn_wgpu::WgpuOptions) -> Result<OpenedBackend> {
        Ok(match self.backend {
            BackendKind::Cpu => {
                let wgpu_only = [
                    (options.recurrence_on_gpu, "--gpu-recurrence"),
                    (options.weights_on_host, "--weights-on-host"),
                    (options.checks != Default::default(), "--wgpu-checks"),
                    (options.profile_kernels, "--profile-kernels"),
                ];
                if let Some((_, flag)) = wgpu_only.iter().find(|(set, _)| *set) {
                    bail!("{flag} needs --backend wgpu");
                }
                (
                    Box::new(pvrnn_core::cpu::CpuBackend),
                    "cpu".to_string(),
                    None,
                )
            }
            BackendKind::Wgpu => {
                let gpu = pvrnn_wgpu::WgpuBackend::new_with(options).context("--backend wgpu")?;
                let mut name = format!("wgpu on {}", gpu.adapter_name());
                if options.recurrence_on_gpu {
                    name.push_str(", recurrence on the GPU");
                }
                if options.weights_on_host {
                    name.push_str(", weights on the host");
                }
                match options.checks {
                    pvrnn_wgpu::RuntimeChecks::Audited => {}
                    pvrnn_wgpu::RuntimeChecks::All => name.push_str(", every kernel checked"),
                    pvrnn_wgpu::RuntimeChecks::None => name.push_str(", no kernel checked"),
                }
                if options.profile_kernels {
                    name.push_str(", each kernel profiled");
                }
                let device = gpu.gpu().clone();
                (Box::new(gpu), name, Some(device))
            }
        })
    }
}
