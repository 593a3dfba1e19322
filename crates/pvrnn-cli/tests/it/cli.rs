//! The `pvrnn` binary end to end: init, free-energy (JSON and gradients), train with
//! checkpoints and resume, infer, config, and clear errors for bad input.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use pvrnn_core::ModelConfig;
use pvrnn_core::config::{ModuleConfig, VisionLayout};
use pvrnn_core::io::{self, TensorFile};

fn pvrnn(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pvrnn"))
        .args(args)
        .output()
        .expect("runs pvrnn")
}

fn ok(args: &[&str]) -> String {
    let out = pvrnn(args);
    assert!(
        out.status.success(),
        "pvrnn {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// Runs `pvrnn` as a cluster job would (stderr not a terminal, plain progress lines every
/// `every` seconds); asserts success and returns stderr.
fn logged(args: &[&str], every: &str) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_pvrnn"))
        .env("PVRNN_PROGRESS_EVERY", every)
        .args(args)
        .output()
        .expect("runs pvrnn");
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "pvrnn {args:?} failed:\n{err}");
    err
}

/// The named columns of a CSV file (a report's tidy table), row by row.
fn csv_columns(path: &Path, names: &[&str]) -> Vec<Vec<String>> {
    let mut table =
        csv::Reader::from_path(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let header = table.headers().unwrap().clone();
    let columns: Vec<usize> = names
        .iter()
        .map(|name| {
            header
                .iter()
                .position(|h| h == *name)
                .unwrap_or_else(|| panic!("{}: no column {name}", path.display()))
        })
        .collect();
    table
        .records()
        .map(|r| {
            let r = r.unwrap();
            columns.iter().map(|&c| r[c].to_string()).collect()
        })
        .collect()
}

fn fails(args: &[&str]) -> String {
    let out = pvrnn(args);
    assert!(!out.status.success(), "pvrnn {args:?} should fail");
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(
        !err.contains("panicked"),
        "panic instead of an error: {err}"
    );
    err
}

/// A small model configuration as TOML (everything else keeps the paper's values).
const SMALL: &str = r#"
kl_weight = 0.01
[executive]
d = 8
z = 3
[associative]
d = 8
z = 3
[exteroceptive]
d = 8
z = 4
[proprioceptive]
d = 8
z = 3
[exteroceptive_readout]
hidden = [8, 10]
[proprioceptive_readout]
hidden = [8]
[vision]
cameras = 2
channels = 3
resolutions = [2, 4]
[train.optimizer]
lr = 0.01
[inference]
window = 4
iterations = 5
"#;

fn small_config() -> ModelConfig {
    let mut c = ModelConfig::default();
    let m = |d, z, tau: [f64; 2]| ModuleConfig { d, z, tau };
    c.executive = m(8, 3, c.executive.tau);
    c.associative = m(8, 3, c.associative.tau);
    c.exteroceptive = m(8, 4, c.exteroceptive.tau);
    c.proprioceptive = m(8, 3, c.proprioceptive.tau);
    c.vision = VisionLayout {
        cameras: 2,
        channels: 3,
        resolutions: vec![2, 4],
    };
    c
}

fn write_inputs(path: &Path, config: &ModelConfig, s: usize, t: usize, poison: bool) {
    let dv = config.vision.dims();
    let mut extero: Vec<f32> = (0..s * t * dv)
        .map(|i| 0.5 * ((i % 97) as f32 * 0.13).sin())
        .collect();
    if poison {
        extero[7] = f32::NAN;
    }
    let proprio: Vec<f32> = (0..s * t * 28)
        .map(|i| 0.6 * ((i % 89) as f32 * 0.07).cos())
        .collect();
    // Written without validation so a NaN file can be produced.
    let mut tensors = std::collections::BTreeMap::new();
    tensors.insert(
        "x_extero".to_string(),
        io::OutTensor::F32(vec![s, t, dv], extero.into()),
    );
    tensors.insert(
        "x_proprio".to_string(),
        io::OutTensor::F32(vec![s, t, 28], proprio.into()),
    );
    io::write_atomic(path, &io::to_bytes(&tensors, Default::default()).unwrap()).unwrap();
}

struct Scratch {
    dir: tempfile::TempDir,
}

impl Scratch {
    fn new() -> Self {
        Self {
            dir: tempfile::tempdir().unwrap(),
        }
    }
    fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }
    fn s(&self, name: &str) -> String {
        self.path(name).display().to_string()
    }
}

fn setup(x: &Scratch) {
    std::fs::write(x.path("small.toml"), SMALL).unwrap();
    write_inputs(&x.path("x.safetensors"), &small_config(), 2, 12, false);
    init_small(x, 3, "m.safetensors");
}

/// A model of the small configuration for 2 x 12 steps, initialised with `seed`, as `name`.
fn init_small(x: &Scratch, seed: u32, name: &str) {
    let seed = seed.to_string();
    ok(&[
        "init",
        "--config",
        &x.s("small.toml"),
        "--sequences",
        "2",
        "--steps",
        "12",
        "--seed",
        &seed,
        "--out",
        &x.s(name),
    ]);
}

#[test]
fn free_energy_prints_the_documented_json_and_gradients() {
    let x = Scratch::new();
    setup(&x);
    let out = ok(&[
        "free-energy",
        "--model",
        &x.s("m.safetensors"),
        "--inputs",
        &x.s("x.safetensors"),
        "--zero-noise",
        "--grads",
        &x.s("g.safetensors"),
    ]);
    let v: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    let acc = v["accuracy"]["exteroceptive"].as_f64().unwrap()
        + v["accuracy"]["proprioceptive"].as_f64().unwrap();
    let cx: f64 = [
        "executive",
        "associative",
        "exteroceptive",
        "proprioceptive",
    ]
    .iter()
    .map(|m| v["complexity"][m].as_f64().unwrap())
    .sum();
    let total = v["total"].as_f64().unwrap();
    assert!(
        (total - (acc + 0.01 * cx)).abs() < 1e-9 * total.abs().max(1.0),
        "{v}"
    );
    assert!(acc > 0.0);
    // Zero noise is deterministic.
    let again = ok(&[
        "free-energy",
        "--model",
        &x.s("m.safetensors"),
        "--inputs",
        &x.s("x.safetensors"),
        "--zero-noise",
    ]);
    assert_eq!(out, again);

    let g = TensorFile::open(&x.path("g.safetensors")).unwrap();
    for name in [
        "grad.executive.w_dd",
        "grad.exteroceptive.out.weight",
        "grad.proprioceptive.a_sigma",
        "grad.associative.w_dh",
    ] {
        assert!(g.contains(name), "{name}");
    }
    assert!(
        !g.contains("grad.executive.bias"),
        "fixed tensors have no gradient"
    );
    assert_eq!(g.shape("grad.exteroceptive.a_mu"), Some(&[2, 12, 4][..]));
}

#[test]
fn train_checkpoints_resumes_and_lowers_free_energy() {
    let x = Scratch::new();
    setup(&x);
    let run = x.s("run.safetensors");
    let first = ok(&[
        "train",
        "--model",
        &x.s("m.safetensors"),
        "--inputs",
        &x.s("x.safetensors"),
        "--out",
        &run,
        "--iterations",
        "30",
        "--checkpoint-every",
        "10",
        "--keep-every",
        "15",
    ]);
    let f30: serde_json::Value = serde_json::from_str(first.trim()).unwrap();
    // --keep-every: a copy at 15 and 30 besides the running checkpoint, the last equal to it.
    assert!(x.path("run.iter15.safetensors").is_file());
    assert!(!x.path("run.iter10.safetensors").exists());
    assert_eq!(
        io::load_model(&x.path("run.iter30.safetensors")).unwrap(),
        io::load_model(&x.path("run.safetensors")).unwrap()
    );
    // Without a terminal (as under nohup or a cluster), plain progress lines at the
    // interval PVRNN_PROGRESS_EVERY sets (0: every update).
    let logged = Command::new(env!("CARGO_BIN_EXE_pvrnn"))
        .env("PVRNN_PROGRESS_EVERY", "0")
        .args([
            "train",
            "--model",
            &x.s("m.safetensors"),
            "--inputs",
            &x.s("x.safetensors"),
            "--out",
            &x.s("logged.safetensors"),
            "--iterations",
            "5",
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&logged.stderr);
    assert!(
        logged.status.success()
            && err.contains("train: 5/5 (100.0%), F ")
            && err.contains("train: 2/5 (40.0%)")
            && err.contains("s each, ETA "),
        "{err}"
    );
    // Refuses to clobber a run.
    let e = fails(&[
        "train",
        "--model",
        &x.s("m.safetensors"),
        "--inputs",
        &x.s("x.safetensors"),
        "--out",
        &run,
        "--iterations",
        "30",
    ]);
    assert!(e.contains("--resume"), "{e}");
    // Resume to 60 and compare with a straight 60-iteration run.
    ok(&[
        "train",
        "--resume",
        "--inputs",
        &x.s("x.safetensors"),
        "--out",
        &run,
        "--iterations",
        "60",
    ]);
    let straight = x.s("straight.safetensors");
    ok(&[
        "train",
        "--model",
        &x.s("m.safetensors"),
        "--inputs",
        &x.s("x.safetensors"),
        "--out",
        &straight,
        "--iterations",
        "60",
        "--checkpoint-every",
        "7",
    ]);
    let a = io::load_model(Path::new(&run)).unwrap();
    let b = io::load_model(Path::new(&straight)).unwrap();
    assert_eq!(a, b, "resumed and straight runs differ");
    // The log has one row per iteration.
    let log = std::fs::read_to_string(x.path("run.log.csv")).unwrap();
    assert_eq!(log.lines().count(), 61, "{log}");
    let last_total: f64 = log
        .lines()
        .last()
        .unwrap()
        .split(',')
        .nth(1)
        .unwrap()
        .parse()
        .unwrap();
    assert!(last_total < f30["total"].as_f64().unwrap());
    // The checkpoint is a model: free-energy reads it.
    ok(&[
        "free-energy",
        "--model",
        &run,
        "--inputs",
        &x.s("x.safetensors"),
    ]);
}

/// SIGTERM (a cluster's time limit, `kill`) writes the checkpoint as Ctrl-C does, and the
/// run resumes from it.
#[cfg(unix)]
#[test]
fn sigterm_writes_a_checkpoint_that_resumes() {
    let x = Scratch::new();
    setup(&x);
    let run = x.s("run.safetensors");
    let child = Command::new(env!("CARGO_BIN_EXE_pvrnn"))
        .args([
            "train",
            "--model",
            &x.s("m.safetensors"),
            "--inputs",
            &x.s("x.safetensors"),
            "--out",
            &run,
            "--iterations",
            "100000000",
            "--checkpoint-every",
            "100000000",
        ])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Wait until it is learning (its log, written in blocks, has rows; or 10 s), then ask
    // it to stop as a scheduler does.
    let log = x.path("run.log.csv");
    let start = std::time::Instant::now();
    while std::fs::read_to_string(&log).map_or(0, |l| l.lines().count()) < 3
        && start.elapsed().as_secs() < 10
    {
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    assert!(
        !x.path("run.safetensors").exists(),
        "checkpoint before the signal"
    );
    let killed = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("interrupted: checkpoint at iteration"),
        "{err}"
    );
    let saved = io::load_checkpoint(&x.path("run.safetensors")).unwrap();
    assert!(saved.iteration >= 1, "iteration {}", saved.iteration);
    // Every logged iteration is in the checkpoint: nothing is lost.
    let rows = std::fs::read_to_string(&log).unwrap().lines().count() as u64 - 1;
    assert_eq!(rows, saved.iteration);
    let resumed_to = (saved.iteration + 2).to_string();
    ok(&[
        "train",
        "--resume",
        "--inputs",
        &x.s("x.safetensors"),
        "--out",
        &run,
        "--iterations",
        &resumed_to,
    ]);
    assert_eq!(
        io::load_checkpoint(&x.path("run.safetensors"))
            .unwrap()
            .iteration,
        saved.iteration + 2
    );
}

/// `pvrnn train` with several --model / --out pairs trains the networks together, each as
/// it trains alone (network k's noise seed: --seed + k), on the CPU and, with the
/// recurrence on the GPU, in one stack on lavapipe (`PVRNN_SKIP_WGPU=1` skips that part).
#[test]
fn train_trains_several_networks_together_as_each_alone() {
    let x = Scratch::new();
    setup(&x);
    init_small(&x, 4, "m2.safetensors");
    let inputs = x.s("x.safetensors");
    // Each pair's final free energy; `seed` is --seed (network k draws with seed + k).
    let train = |pairs: &[(&str, &str)], seed: &str, extra: &[&str]| -> Vec<f64> {
        let mut args = vec!["train".to_string()];
        for (model, out) in pairs {
            args.extend(["--model".into(), x.s(model), "--out".into(), x.s(out)]);
        }
        let common = ["--inputs", &inputs, "--iterations", "6", "--seed", seed];
        args.extend(common.iter().chain(extra).map(|a| a.to_string()));
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        ok(&args)
            .lines()
            .map(|l| {
                serde_json::from_str::<serde_json::Value>(l).unwrap()["total"]
                    .as_f64()
                    .unwrap()
            })
            .collect()
    };
    let weights = |out: &str| io::load_model(&x.path(out)).unwrap();
    let mut backends: Vec<&[&str]> = vec![&["--backend", "cpu"]];
    if std::env::var_os("PVRNN_SKIP_WGPU").is_none() {
        backends.push(&["--backend", "wgpu", "--gpu-recurrence"]);
    }
    for (b, backend) in backends.into_iter().enumerate() {
        let (a0, a1, t0, t1) = (
            format!("a0-{b}.safetensors"),
            format!("a1-{b}.safetensors"),
            format!("t0-{b}.safetensors"),
            format!("t1-{b}.safetensors"),
        );
        let alone0 = train(&[("m.safetensors", &a0)], "5", backend)[0];
        // Alone, network 1 draws with seed 6 (--seed 5 + 1).
        let alone1 = train(&[("m2.safetensors", &a1)], "6", backend)[0];
        let together = train(
            &[("m.safetensors", &t0), ("m2.safetensors", &t1)],
            "5",
            backend,
        );
        assert_eq!(
            together,
            vec![alone0, alone1],
            "{backend:?}: final free energies"
        );
        assert_eq!(weights(&a0), weights(&t0), "{backend:?}: network 0");
        assert_eq!(weights(&a1), weights(&t1), "{backend:?}: network 1");
    }
    let e = fails(&[
        "train",
        "--model",
        &x.s("m.safetensors"),
        "--inputs",
        &x.s("x.safetensors"),
        "--out",
        &x.s("u.safetensors"),
        "--out",
        &x.s("v.safetensors"),
    ]);
    assert!(e.contains("1 --model but 2 --out"), "{e}");
    let e = fails(&[
        "train",
        "--model",
        &x.s("m.safetensors"),
        "--model",
        &x.s("m2.safetensors"),
        "--inputs",
        &x.s("x.safetensors"),
        "--out",
        &x.s("u.safetensors"),
        "--out",
        &x.s("u.safetensors"),
    ]);
    assert!(e.contains("its own --out"), "{e}");
}

/// A real out-of-memory, not a stand-in: lavapipe's device memory is the process's own, so
/// an address-space limit (`ulimit -v`, 4.5 GB) that the program and the 16 networks' host
/// copies fit in, and their device buffers (about 3.6 GB at 4 sequences of 300 steps) with
/// them do not, makes the device run out while the cohort is being made or its first
/// iteration submitted. Either must be an error that says so and what to do, exit status
/// 1: not wgpu's panic (101), an abort, or a hang. Measured on the 2-core CI machines'
/// kind (2026-12-01): 16 networks fail cleanly from 3.5 to 4.5 GB; at 3 GB the host's own
/// allocations run out first, and at 6 GB 8 networks train.
#[cfg(target_os = "linux")]
#[test]
fn a_cohort_the_device_memory_cannot_hold_is_a_clear_error() {
    if std::env::var_os("PVRNN_SKIP_WGPU").is_some() {
        return;
    }
    let shader_cache = Scratch::new();
    let (status, err) = bench_under_memory_limit(
        Some(4_500_000),
        &["--gpu-recurrence", "--networks", "16", "--sequences", "4"],
        shader_cache.dir.path(),
    );
    assert_eq!(
        status.code(),
        Some(1),
        "expected a clear error, got {status}:\n{err}"
    );
    assert!(
        err.contains("of 16 networks trained together")
            && err.contains("out of memory; train fewer networks at once"),
        "{err}"
    );
}

/// Without `--gpu-recurrence` the read-outs allocate per call, on whatever thread
/// evaluates, where no error scope covers them: running out of device memory there is
/// recorded as the device's failure and ends the run with a clear error (exit 1), before
/// the host goes on to the way back. Before 2026-12-02 it was wgpu's panic (exit 101).
/// The same command first runs without a limit (it must succeed: what fails below is
/// memory), which also fills a private shader cache: lavapipe compiles the kernels with
/// LLVM on first use, and on a cold cache that compilation's own allocations can run out
/// before the device's do (an abort, as seen on a fresh machine at 1.3 GB). Measured with
/// the cache warm, on two machines of the CI's kind: one network of 8 sequences fails
/// cleanly from 1.1-1.2 to 1.5 GB; below that the host's own allocations run out first,
/// and from 1.7-1.75 GB the device's allocations fit and the host's run out later.
#[cfg(target_os = "linux")]
#[test]
fn a_read_out_the_device_memory_cannot_hold_is_a_clear_error() {
    if std::env::var_os("PVRNN_SKIP_WGPU").is_some() {
        return;
    }
    let shader_cache = Scratch::new();
    let args = ["--sequences", "8"];
    let (status, err) = bench_under_memory_limit(None, &args, shader_cache.dir.path());
    assert!(status.success(), "without a limit: {status}:\n{err}");
    let (status, err) = bench_under_memory_limit(Some(1_400_000), &args, shader_cache.dir.path());
    assert_eq!(
        status.code(),
        Some(1),
        "expected a clear error, got {status}:\n{err}"
    );
    assert!(
        err.contains("out of memory") && err.contains("evaluate or train fewer networks at once"),
        "{err}"
    );
}

/// One learning iteration of `pvrnn bench --backend wgpu` at 300 steps with `extra`, its
/// address space limited to `limit_kb` where given (on lavapipe device memory is the
/// process's own), Mesa's shader cache in `shader_cache`: the exit status and the
/// standard error. Killed after 300 s (a hang fails).
#[cfg(target_os = "linux")]
fn bench_under_memory_limit(
    limit_kb: Option<u64>,
    extra: &[&str],
    shader_cache: &Path,
) -> (std::process::ExitStatus, String) {
    let limit = limit_kb.map_or("unlimited".to_string(), |kb| kb.to_string());
    let mut child = Command::new("sh")
        .arg("-c")
        .arg(format!(r#"ulimit -v {limit} && exec "$0" "$@""#))
        .arg(env!("CARGO_BIN_EXE_pvrnn"))
        .args([
            "--threads",
            "2",
            "bench",
            "--backend",
            "wgpu",
            "--only",
            "train",
        ])
        .args(["--steps", "300", "--train-iterations", "1"])
        .args(extra)
        // glibc's per-thread arenas reserve address space by the core count.
        .env("MALLOC_ARENA_MAX", "2")
        .env("MESA_SHADER_CACHE_DIR", shader_cache)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("runs pvrnn under sh");
    let started = std::time::Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if started.elapsed() > std::time::Duration::from_secs(300) {
            child.kill().ok();
            panic!("pvrnn out of device memory did not finish in 300 s");
        }
        std::thread::sleep(std::time::Duration::from_millis(200));
    };
    let out = child.wait_with_output().unwrap();
    (status, String::from_utf8_lossy(&out.stderr).into_owned())
}

/// The wgpu backend's defaults learn bit for bit as the build before its switches became
/// typed options and the variants without a measured win were deleted (2026-12-06): six
/// iterations of the small model on 24 rows (the fused output kernels), on 160 rows (the
/// blocked ones), and on 160 rows with `--gpu-recurrence` (the whole iteration on the
/// device, replayed and queued ahead), each final free energy as that build gave it on
/// lavapipe (Mesa 22.3.6, the tests' CPU Vulkan device). Another adapter or driver may
/// round otherwise: skipped there. `PVRNN_SKIP_WGPU=1` skips it too.
#[test]
fn the_wgpu_defaults_learn_the_bits_they_learned_before() {
    if std::env::var_os("PVRNN_SKIP_WGPU").is_some() {
        return;
    }
    let x = Scratch::new();
    setup(&x);
    write_inputs(&x.path("x40.safetensors"), &small_config(), 4, 40, false);
    let config = x.s("small.toml");
    let m40 = x.s("m40.safetensors");
    let init = [
        "init",
        "--config",
        &config,
        "--sequences",
        "4",
        "--steps",
        "40",
    ];
    ok(&[&init[..], &["--seed", "1", "--out", &m40]].concat());
    let train = |model: &str, inputs: &str, extra: &[&str]| {
        let out = x.s("out.safetensors");
        let mut args = vec![
            "--threads",
            "2",
            "train",
            "--model",
            model,
            "--inputs",
            inputs,
        ];
        args.extend([
            "--out",
            &out,
            "--overwrite",
            "--iterations",
            "6",
            "--seed",
            "5",
        ]);
        args.extend(["--backend", "wgpu"]);
        args.extend_from_slice(extra);
        let out = pvrnn(&args);
        let err = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(out.status.success(), "train {extra:?} failed:\n{err}");
        let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        (report["total"].as_f64().unwrap(), err)
    };
    let (m12, x12, x40) = (
        x.s("m.safetensors"),
        x.s("x.safetensors"),
        x.s("x40.safetensors"),
    );
    let (fused, err) = train(&m12, &x12, &[]);
    if !(err.contains("llvmpipe") && err.contains("Mesa 22.3.6")) {
        eprintln!("skipped: the recorded bits are lavapipe's (Mesa 22.3.6):\n{err}");
        return;
    }
    let (blocked, _) = train(&m40, &x40, &[]);
    let (whole, _) = train(&m40, &x40, &["--gpu-recurrence"]);
    let got = [fused, blocked, whole].map(f64::to_bits);
    // 5.184906377458855, 29.55531036540866 and 29.55531037936608, recorded with the build
    // of commit 443c14a.
    let before: [u64; 3] = [
        4617523704034756556,
        4629012297978908508,
        4629012297982837173,
    ];
    assert_eq!(
        got,
        before,
        "free energies {:?} against {:?} before",
        got.map(f64::from_bits),
        before.map(f64::from_bits)
    );
}

/// `--backend wgpu` (on a CPU Vulkan device where there is no GPU): learning gives the CPU
/// backend's free energy to f32 summation order, and inference runs; a run says which
/// backend it used. `PVRNN_SKIP_WGPU=1` skips it on a machine without a Vulkan driver.
#[test]
fn train_and_infer_run_on_the_wgpu_backend() {
    if std::env::var_os("PVRNN_SKIP_WGPU").is_some() {
        return;
    }
    let x = Scratch::new();
    setup(&x);
    let train = |backend: &[&str]| {
        let name = backend.join(" ");
        let file = backend.join("_").replace("--", "");
        let mut args = vec![
            "train".to_string(),
            "--model".into(),
            x.s("m.safetensors"),
            "--inputs".into(),
            x.s("x.safetensors"),
            "--out".into(),
            x.s(&format!("{file}.safetensors")),
            "--iterations".into(),
            "10".into(),
        ];
        args.extend(backend.iter().map(|a| a.to_string()));
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let out = pvrnn(&args);
        let err = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(out.status.success(), "train {name} failed:\n{err}");
        let report: serde_json::Value =
            serde_json::from_slice(&out.stdout).expect("train prints its final free energy");
        (report["total"].as_f64().unwrap(), err)
    };
    let (cpu, _) = train(&["--backend", "cpu"]);
    let (gpu, err) = train(&["--backend", "wgpu"]);
    assert!(err.contains("backend: wgpu on "), "{err}");
    assert!(
        err.contains("trainable tensors (the rest updated on the CPU)"),
        "{err}"
    );
    assert!(
        (cpu - gpu).abs() <= 1e-4 * cpu.abs(),
        "after 10 iterations: cpu F {cpu}, wgpu F {gpu}"
    );
    // The weights uploaded every iteration instead of kept on the GPU: the same learning.
    let (on_host, err) = train(&["--backend", "wgpu", "--weights-on-host"]);
    assert!(err.contains("weights on the host"), "{err}");
    assert!(!err.contains("on the GPU for the whole run"), "{err}");
    assert!(
        (cpu - on_host).abs() <= 1e-4 * cpu.abs(),
        "after 10 iterations: cpu F {cpu}, wgpu with the weights on the host F {on_host}"
    );
    // The recurrence on the GPU too: the same learning, and the run says so.
    let (all_gpu, err) = train(&["--backend", "wgpu", "--gpu-recurrence"]);
    assert!(err.contains("recurrence on the GPU"), "{err}");
    assert!(err.contains("each iteration runs there whole"), "{err}");
    assert!(
        (cpu - all_gpu).abs() <= 1e-4 * cpu.abs(),
        "after 10 iterations: cpu F {cpu}, wgpu with the recurrence F {all_gpu}"
    );
    // wgpu's runtime checks in every kernel (`--wgpu-checks all`) and in none: the same
    // learning, and the run says so.
    for (checks, said) in [
        ("all", "every kernel checked"),
        ("none", "no kernel checked"),
    ] {
        let args = [
            "--backend",
            "wgpu",
            "--gpu-recurrence",
            "--wgpu-checks",
            checks,
        ];
        let (checked, err) = train(&args);
        assert!(err.contains(said), "{err}");
        assert!(
            (all_gpu - checked).abs() <= 1e-5 * all_gpu.abs(),
            "after 10 iterations: wgpu F {all_gpu}, with --wgpu-checks {checks} F {checked}"
        );
    }
    ok(&[
        "infer",
        "--model",
        &x.s("backend_wgpu.safetensors"),
        "--inputs",
        &x.s("x.safetensors"),
        "--out",
        &x.s("r.safetensors"),
        "--sequences",
        "0",
        "--backend",
        "wgpu",
    ]);
    let f = TensorFile::open(&x.path("r.safetensors")).unwrap();
    assert_eq!(
        f.shape("recon.exteroceptive"),
        Some(&[1, 12, small_config().vision.dims()][..])
    );
    // free-energy on either backend: the same terms to f32 summation order (the small
    // model's output layers stay on the CPU, its recurrence runs on the GPU with
    // `--gpu-recurrence`).
    let (model, inputs) = (x.s("m.safetensors"), x.s("x.safetensors"));
    let free_energy = |backend: &[&str]| {
        let mut args = vec!["free-energy", "--model", &model, "--inputs", &inputs];
        args.extend_from_slice(backend);
        let out = ok(&args);
        let v: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
        v["total"].as_f64().unwrap()
    };
    let cpu = free_energy(&["--backend", "cpu"]);
    for backend in [
        &["--backend", "wgpu"][..],
        &["--backend", "wgpu", "--gpu-recurrence"],
    ] {
        let gpu = free_energy(backend);
        assert!(
            (cpu - gpu).abs() <= 1e-5 * cpu.abs(),
            "free-energy: cpu {cpu}, {backend:?} {gpu}"
        );
    }
}

/// An experiment on the wgpu backend, two jobs at once sharing one device (lavapipe where
/// there is no GPU): every training and inference run gives the CPU backend's numbers to
/// f32 summation order, and every result says what computed it.
#[test]
fn an_experiment_runs_on_the_wgpu_backend_with_jobs_sharing_the_device() {
    if std::env::var_os("PVRNN_SKIP_WGPU").is_some() {
        return;
    }
    let x = Scratch::new();
    // 12 steps: network 0 has 8 trainings (both directions) on each backend.
    pvrnn_dataset::synthetic::caresim_like(&[590, 650, 710], 3, 1, 12)
        .unwrap()
        .write(&x.path("ds"))
        .unwrap();
    let run = |backend: &str| {
        let out = x.s(backend);
        let err = logged(
            &[
                "--threads",
                "2",
                "experiment",
                "interference",
                "--scale",
                "smoke",
                "--dataset",
                &x.s("ds"),
                "--out",
                &out,
                "--network",
                "0",
                "--jobs",
                "2",
                "--backend",
                backend,
            ],
            "60",
        );
        assert!(
            err.contains("backend: wgpu on ") || backend == "cpu",
            "{err}"
        );
        let report = |file: &str| x.path(&format!("{backend}/report/{file}"));
        let mut rows: Vec<(String, f64, String)> = csv_columns(
            &report("trainings.csv"),
            &["job", "final_free_energy", "backend"],
        )
        .into_iter()
        .map(|r| (r[0].clone(), r[1].parse().unwrap(), r[2].clone()))
        .collect();
        rows.sort_by(|a, b| a.0.cmp(&b.0));
        let mut errors: Vec<(String, f64)> =
            csv_columns(&report("trials.csv"), &["job", "error_proprio"])
                .into_iter()
                .map(|r| (r[0].clone(), r[1].parse().unwrap()))
                .collect();
        errors.sort_by(|a, b| a.0.cmp(&b.0));
        (rows, errors)
    };
    let (cpu, cpu_errors) = run("cpu");
    let (gpu, gpu_errors) = run("wgpu");
    assert_eq!(cpu.len(), 8, "network 0's 2 directions x 4 conditions");
    assert_eq!(gpu.len(), cpu.len());
    assert!(!cpu_errors.is_empty());
    assert_eq!(gpu_errors.len(), cpu_errors.len());
    for ((name, f_cpu, by_cpu), (_, f_gpu, by_gpu)) in cpu.iter().zip(&gpu) {
        assert!(
            by_cpu.starts_with("cpu, ") && by_gpu.starts_with("wgpu on "),
            "{by_cpu} / {by_gpu}"
        );
        // 20 iterations of RAdam from the same start: f32 summation order only.
        assert!(
            (f_cpu - f_gpu).abs() <= 1e-4 * f_cpu.abs(),
            "{name}: cpu F {f_cpu}, wgpu F {f_gpu}"
        );
    }
    for ((name, e_cpu), (_, e_gpu)) in cpu_errors.iter().zip(&gpu_errors) {
        assert!(
            (e_cpu - e_gpu).abs() <= 1e-3 * e_cpu.abs(),
            "{name}: cpu error {e_cpu}, wgpu error {e_gpu}"
        );
    }
}

/// `pvrnn bench --json` of one timed training iteration of 1 x 33 steps, with `extra`.
fn small_train_bench(extra: &[&str]) -> serde_json::Value {
    let mut args = vec![
        "bench",
        "--sequences",
        "1",
        "--steps",
        "33",
        "--train-iterations",
        "1",
        "--only",
        "train",
        "--json",
    ];
    args.extend_from_slice(extra);
    serde_json::from_str(ok(&args).trim()).unwrap()
}

/// `pvrnn bench --profile` says where a training iteration's time goes: phases that
/// nest inside `evaluate`, each a non-negative number of milliseconds.
#[test]
fn bench_profile_names_the_phases_of_an_iteration() {
    let v = small_train_bench(&["--profile"]);
    assert!(v["train_iter_s"].as_f64().unwrap() > 0.0, "{v}");
    let parts = v["profile"].as_array().expect("a profile");
    assert_eq!(parts.len(), 1, "only training was run: {v}");
    assert_eq!(parts[0]["part"], "train");
    let phases: Vec<(String, f64, f64)> = parts[0]["phases"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            (
                p["phase"].as_str().unwrap().trim().to_string(),
                p["ms"].as_f64().unwrap(),
                p["times"].as_f64().unwrap(),
            )
        })
        .collect();
    let phase = |name: &str| {
        phases
            .iter()
            .find(|(n, ..)| n == name)
            .unwrap_or_else(|| panic!("no phase {name} in {phases:?}"))
    };
    let ms = |name: &str| phase(name).1;
    let times = |name: &str| phase(name).2;
    for (_, t, _) in &phases {
        assert!(*t >= 0.0, "{phases:?}");
    }
    // How often each phase ran per iteration: the one timed iteration evaluated once.
    assert_eq!(times("evaluate"), 1.0, "{phases:?}");
    // Parts never exceed the whole they are in.
    let evaluate = ms("evaluate");
    let inside = ms("recurrence forward") + ms("read-out output layer") + ms("recurrence backward");
    assert!(inside <= evaluate * 1.001 + 1e-3, "{phases:?}");
    assert!(ms("optimiser (RAdam)") > 0.0, "{phases:?}");
    // Without --profile there is no profile.
    let plain = small_train_bench(&[]);
    assert!(plain.get("profile").is_none(), "{plain}");
    // The free energy of the warm-up and the timed iteration, from seeded data and noise:
    // two runs (or two backends) can be compared number by number.
    let free_energy = |v: &serde_json::Value| -> Vec<f64> {
        let terms = v["train_free_energy"].as_array().expect("free energies");
        terms.iter().map(|f| f.as_f64().unwrap()).collect()
    };
    let first = free_energy(&v);
    assert_eq!(first.len(), 2, "warm-up and one timed iteration: {v}");
    assert!(first.iter().all(|f| f.is_finite() && *f > 0.0), "{v}");
    assert_eq!(first, free_energy(&plain), "the same seeded run twice");
    assert!(
        v["gpu_buffer_mb"].is_null(),
        "no GPU memory on the CPU: {v}"
    );
}

/// `pvrnn bench --profile --profile-kernels` on the wgpu backend with the recurrence there
/// lists each kernel's device time beside each part's ("device: kernel <label>"), where
/// the adapter has timestamp queries; without `--profile` the flag is refused.
#[test]
fn bench_profile_kernels_on_the_wgpu_backend_lists_each_kernel() {
    if std::env::var_os("PVRNN_SKIP_WGPU").is_some() {
        return;
    }
    let wgpu = ["--backend", "wgpu", "--gpu-recurrence", "--profile"];
    let phases = |extra: &[&str]| -> Vec<String> {
        let args: Vec<&str> = wgpu.iter().chain(extra).copied().collect();
        let v = small_train_bench(&args);
        v["profile"][0]["phases"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p["phase"].as_str().unwrap().trim().to_string())
            .collect()
    };
    let parts = phases(&[]);
    let kernel = |p: &String| p.starts_with("device: kernel ");
    assert!(!parts.iter().any(kernel), "{parts:?}");
    if parts.iter().any(|p| p.starts_with("device: ")) {
        let kernels = phases(&["--profile-kernels"]);
        assert!(
            kernels
                .iter()
                .any(|p| p == "device: kernel recurrence backward"),
            "{kernels:?}"
        );
    }
    let e = fails(&["bench", "--backend", "wgpu", "--profile-kernels"]);
    assert!(e.contains("--profile"), "{e}");
}

/// `--networks N` trains N networks together: the figures are per iteration of all of
/// them, network 0's free energies are the single run's, and on a GPU (lavapipe here)
/// the device memory its buffers hold grows with N. `PVRNN_SKIP_WGPU=1` skips the GPU part.
#[test]
fn bench_trains_several_networks_together() {
    let bench = small_train_bench;
    let free_energy = |v: &serde_json::Value| v["train_free_energy"].clone();
    let one = bench(&[]);
    let three = bench(&["--networks", "3"]);
    assert_eq!(three["networks"], 3, "{three}");
    let (mean, rate) = (
        three["train_iter_s"].as_f64().unwrap(),
        three["network_iterations_per_s"].as_f64().unwrap(),
    );
    assert!((rate - 3.0 / mean).abs() < 1e-9 * rate, "{three}");
    assert_eq!(
        free_energy(&one),
        free_energy(&three),
        "network 0 is the single run"
    );
    let e = fails(&["bench", "--networks", "0"]);
    assert!(e.contains("--networks"), "{e}");
    if std::env::var_os("PVRNN_SKIP_WGPU").is_some() {
        return;
    }
    let gpu = |n: &str| bench(&["--backend", "wgpu", "--gpu-recurrence", "--networks", n]);
    let (one, two) = (gpu("1"), gpu("2"));
    assert_eq!(
        free_energy(&one),
        free_energy(&two),
        "network 0 is the single run"
    );
    let (m1, m2) = (
        one["gpu_buffer_mb"]
            .as_f64()
            .expect("the GPU's buffer memory"),
        two["gpu_buffer_mb"]
            .as_f64()
            .expect("the GPU's buffer memory"),
    );
    assert!(
        m1 > 0.0 && m2 > m1,
        "buffer memory with 1 and 2 networks: {m1} and {m2} MB"
    );
}

#[test]
fn infer_writes_per_step_outputs_under_conditions() {
    let x = Scratch::new();
    setup(&x);
    let out = x.s("r.safetensors");
    ok(&[
        "infer",
        "--model",
        &x.s("m.safetensors"),
        "--inputs",
        &x.s("x.safetensors"),
        "--out",
        &out,
        "--vision",
        "2",
        "--proprio",
        "off",
        "--ablate",
        "executive",
        "--sequences",
        "1",
        "--iterations",
        "3",
    ]);
    let f = TensorFile::open(Path::new(&out)).unwrap();
    assert_eq!(
        f.shape("recon.exteroceptive"),
        Some(&[1, 12, small_config().vision.dims()][..])
    );
    assert_eq!(f.shape("prior.proprioceptive"), Some(&[1, 12, 28][..]));
    assert_eq!(f.shape("exteroceptive.sigma_q"), Some(&[1, 12, 4][..]));
    assert_eq!(f.shape("associative.d"), Some(&[1, 12, 8][..]));
    assert_eq!(f.indices("sequence").unwrap(), vec![1]);
    let settings = f.metadata("settings").unwrap();
    assert!(
        settings.contains("\"vision_levels\":1") && settings.contains("\"proprio\":false"),
        "{settings}"
    );
    assert!(settings.contains("\"iterations\":3"), "{settings}");
    let e = fails(&[
        "infer",
        "--model",
        &x.s("m.safetensors"),
        "--inputs",
        &x.s("x.safetensors"),
        "--out",
        &out,
        "--vision",
        "8",
    ]);
    assert!(e.contains("lowest"), "{e}");
    let e = fails(&[
        "infer",
        "--model",
        &x.s("m.safetensors"),
        "--inputs",
        &x.s("x.safetensors"),
        "--out",
        &out,
        "--ablate",
        "cortex",
    ]);
    assert!(e.contains("unknown module `cortex`"), "{e}");
}

#[test]
fn bad_inputs_give_clear_errors() {
    let x = Scratch::new();
    setup(&x);
    let m = x.s("m.safetensors");
    let e = fails(&[
        "free-energy",
        "--model",
        &x.s("missing.safetensors"),
        "--inputs",
        &x.s("x.safetensors"),
    ]);
    assert!(
        e.contains("missing.safetensors") && e.contains("No such file"),
        "{e}"
    );

    let e = fails(&[
        "free-energy",
        "--model",
        &m,
        "--inputs",
        &x.s("x.safetensors"),
        "--gpu-recurrence",
    ]);
    assert!(e.contains("--gpu-recurrence needs --backend wgpu"), "{e}");
    let e = fails(&[
        "free-energy",
        "--model",
        &m,
        "--inputs",
        &x.s("x.safetensors"),
        "--weights-on-host",
    ]);
    assert!(e.contains("--weights-on-host needs --backend wgpu"), "{e}");
    let e = fails(&[
        "free-energy",
        "--model",
        &m,
        "--inputs",
        &x.s("x.safetensors"),
        "--wgpu-checks",
        "all",
    ]);
    assert!(e.contains("--wgpu-checks needs --backend wgpu"), "{e}");
    // A learning option, refused by the commands that only run online inference.
    let e = fails(&[
        "infer",
        "--model",
        &m,
        "--inputs",
        &x.s("x.safetensors"),
        "--out",
        &x.s("never.safetensors"),
        "--backend",
        "wgpu",
        "--gpu-recurrence",
    ]);
    assert!(
        e.contains("--gpu-recurrence is a learning option and `pvrnn infer`"),
        "{e}"
    );

    write_inputs(&x.path("nan.safetensors"), &small_config(), 2, 12, true);
    let e = fails(&[
        "free-energy",
        "--model",
        &m,
        "--inputs",
        &x.s("nan.safetensors"),
    ]);
    assert!(
        e.contains("nan.safetensors") && e.contains("x_extero") && e.contains("non-finite"),
        "{e}"
    );

    write_inputs(&x.path("three.safetensors"), &small_config(), 3, 12, false);
    let e = fails(&[
        "train",
        "--model",
        &m,
        "--inputs",
        &x.s("three.safetensors"),
        "--out",
        &x.s("o.safetensors"),
        "--iterations",
        "1",
    ]);
    assert!(
        e.contains("2 sequences of 12 steps") && e.contains("3 sequences"),
        "{e}"
    );

    write_inputs(
        &x.path("paper.safetensors"),
        &ModelConfig::default(),
        2,
        12,
        false,
    );
    let e = fails(&[
        "infer",
        "--model",
        &m,
        "--inputs",
        &x.s("paper.safetensors"),
        "--out",
        &x.s("o.safetensors"),
    ]);
    assert!(
        e.contains("x_extero has 32256 dimensions per step but the model expects 120"),
        "{e}"
    );

    let bytes = std::fs::read(x.path("m.safetensors")).unwrap();
    std::fs::write(x.path("cut.safetensors"), &bytes[..bytes.len() / 2]).unwrap();
    let e = fails(&[
        "free-energy",
        "--model",
        &x.s("cut.safetensors"),
        "--inputs",
        &x.s("x.safetensors"),
    ]);
    assert!(
        e.contains("cut.safetensors") && e.contains("truncated"),
        "{e}"
    );

    std::fs::write(x.path("bad.toml"), "[executive]\nd = -3\n").unwrap();
    let e = fails(&[
        "init",
        "--config",
        &x.s("bad.toml"),
        "--sequences",
        "1",
        "--steps",
        "2",
        "--out",
        &x.s("o.safetensors"),
    ]);
    assert!(e.contains("bad.toml"), "{e}");
    let e = fails(&[
        "train",
        "--resume",
        "--inputs",
        &x.s("x.safetensors"),
        "--out",
        &m,
    ]);
    assert!(e.contains("not a checkpoint"), "{e}");
}

#[test]
fn config_prints_toml_that_init_accepts() {
    let x = Scratch::new();
    let text = ok(&["config"]);
    assert!(text.contains("kl_weight = 0.005"));
    std::fs::write(x.path("paper.toml"), &text).unwrap();
    ok(&[
        "init",
        "--config",
        &x.s("paper.toml"),
        "--sequences",
        "1",
        "--steps",
        "3",
        "--out",
        &x.s("p.safetensors"),
    ]);
    let model = io::load_model(&x.path("p.safetensors")).unwrap();
    assert_eq!(model.config, ModelConfig::default());
    let from_model = ok(&["config", "--model", &x.s("p.safetensors")]);
    assert_eq!(from_model, text);
}

/// Every named recipe in `training/recipes/` is a configuration `init` accepts, and departs
/// from the paper in exactly what its README row says it does.
#[test]
fn every_recipe_is_a_valid_named_departure() {
    let x = Scratch::new();
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../training/recipes");
    let readme = std::fs::read_to_string(dir.join("README.md")).unwrap();
    let mut names = Vec::new();
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "toml") {
            continue;
        }
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let out = x.s(&format!("{name}.safetensors"));
        let path = path.display().to_string();
        ok(&[
            "init",
            "--config",
            &path,
            "--sequences",
            "1",
            "--steps",
            "3",
            "--out",
            &out,
        ]);
        let departures = io::load_model(Path::new(&out))
            .unwrap()
            .config
            .departures_from_paper();
        assert!(
            !departures.is_empty(),
            "{name} is the paper's configuration"
        );
        assert!(
            readme.contains(&format!("| `{name}` |")),
            "{name} is not in the README"
        );
        names.push(name);
    }
    assert!(names.len() >= 5, "{names:?}");
}

#[test]
fn simulate_then_learn_and_infer_from_the_dataset_folder() {
    let x = Scratch::new();
    let ds = x.s("ds");
    let err = logged(
        &[
            "simulate",
            "--out",
            &ds,
            "--tasks",
            "wiping",
            "--heights",
            "650",
            "--learn-per-height",
            "1",
            "--test-per-height",
            "1",
            "--seed",
            "4",
        ],
        "0.2",
    );
    // Lines keep coming at the interval while a sequence (over a second each) is rendered,
    // not only when one finishes.
    assert!(
        err.contains("simulate: 0/2 (0.0%)") && err.contains("simulate: 2/2 (100.0%)"),
        "{err}"
    );
    let dataset = pvrnn_dataset::Dataset::open(&x.path("ds")).unwrap();
    assert_eq!(dataset.sequences.len(), 2);
    // The default: the paper's variability, no robot-free renders.
    assert_eq!(dataset.manifest.source, "caresim (seed 4)");
    assert!(
        dataset
            .sequences
            .iter()
            .all(|s| s.images_without_robot.is_none())
    );
    let e = fails(&[
        "simulate",
        "--out",
        &x.s("bad"),
        "--variability",
        "cooking=1",
    ]);
    assert!(e.contains("unknown task `cooking`"), "{e}");
    for s in &dataset.sequences {
        let stem = pvrnn_dataset::file_stem(&s.info.name);
        assert!(
            x.path("ds")
                .join("previews")
                .join(format!("{stem}.png"))
                .is_file()
        );
        assert!(
            x.path("ds")
                .join("previews")
                .join(format!("{stem}.gif"))
                .is_file()
        );
    }
    // A small model sized and scaled by the dataset, the paper's vision layout.
    std::fs::write(x.path("small.toml"), "[executive]\nd = 6\nz = 2\n[associative]\nd = 6\nz = 2\n[exteroceptive]\nd = 6\nz = 3\n[proprioceptive]\nd = 6\nz = 2\n[inference]\nwindow = 5\niterations = 2\n").unwrap();
    let m = x.s("m.safetensors");
    ok(&[
        "init",
        "--config",
        &x.s("small.toml"),
        "--dataset",
        &ds,
        "--out",
        &m,
    ]);
    let model = io::load_model(Path::new(&m)).unwrap();
    assert_eq!(model.adaptive.sequences(), 1);
    let norm = model
        .config
        .normalisation
        .as_ref()
        .expect("init --dataset stores the ranges");
    assert!(norm.proprio_max[14] > norm.proprio_min[14]);
    let run = x.s("run.safetensors");
    ok(&[
        "train",
        "--model",
        &m,
        "--inputs",
        &ds,
        "--out",
        &run,
        "--iterations",
        "2",
    ]);
    // Early stopping: scored on the dataset's sequences every iteration, the best kept; a
    // resumed run goes on with the same log.
    let early = x.s("early.safetensors");
    let validate = |iterations: &str, resume: bool| {
        let mut args = vec![
            "train",
            "--inputs",
            &ds,
            "--out",
            &early,
            "--iterations",
            iterations,
            "--validate",
            &ds,
            "--validate-every",
            "1",
        ];
        if resume {
            args.push("--resume");
        } else {
            args.extend(["--model", &m]);
        }
        logged(&args, "0")
    };
    let err = validate("2", false);
    assert!(
        err.contains("validation at iteration 1: reconstruction error")
            && err.contains("validation at iteration 2: reconstruction error")
            && err.contains("warning: --validate")
            && err.contains("is the training data"),
        "{err}"
    );
    validate("3", true);
    let rows = pvrnn_eval::validation::read_log(&x.path("early.validation.csv")).unwrap();
    assert_eq!(
        rows.iter().map(|r| r.iteration).collect::<Vec<_>>(),
        [1, 2, 3]
    );
    assert!(
        rows.iter()
            .all(|r| r.trials == 2 && r.failed_trials == 0 && r.recon_vision_top.is_finite()),
        "{rows:?}"
    );
    let best = pvrnn_eval::validation::best(&rows).unwrap().iteration;
    let kept = TensorFile::open(&x.path("early.best.safetensors")).unwrap();
    assert_eq!(io::checkpoint_iteration(&kept), Some(best));
    assert!(
        rows.iter()
            .all(|r| r.upsample.is_some() && r.mean.is_some())
    );
    // --patience 1: the run stops at the first validation that does not beat the best,
    // with its checkpoint at that iteration, or runs to the end if every one did.
    let err = logged(
        &[
            "train",
            "--inputs",
            &ds,
            "--out",
            &early,
            "--iterations",
            "12",
            "--validate",
            &ds,
            "--validate-every",
            "1",
            "--patience",
            "1",
            "--resume",
        ],
        "0",
    );
    let rows = pvrnn_eval::validation::read_log(&x.path("early.validation.csv")).unwrap();
    let best = pvrnn_eval::validation::best(&rows).unwrap().iteration;
    let last = rows.last().unwrap().iteration;
    let reached = io::checkpoint_iteration(&TensorFile::open(Path::new(&early)).unwrap());
    assert_eq!(reached, Some(last));
    if last < 12 {
        assert_eq!(
            last,
            rows.iter().find(|r| r.iteration > best).unwrap().iteration
        );
        assert!(
            err.contains("stopped early at iteration") && err.contains("did not beat it"),
            "{err}"
        );
    } else {
        assert!(rows.windows(2).all(|w| w[1].better_than(&w[0])), "{rows:?}");
    }
    // Plotted beside another run's log, with the baselines.
    ok(&[
        "report",
        "validation",
        &format!("paper={}", x.s("early.validation.csv")),
        &format!("again={}", x.s("early.validation.csv")),
        "--out",
        &x.s("validation.png"),
    ]);
    let png = std::fs::read(x.path("validation.png")).unwrap();
    assert!(
        png.starts_with(b"\x89PNG") && png.len() > 10_000,
        "{} bytes",
        png.len()
    );
    let e = fails(&["report", "validation", "paper", "--out", &x.s("v.png")]);
    assert!(e.contains("NAME=FILE"), "{e}");
    let missing = x.s("no-such-dataset");
    let e = fails(&[
        "train",
        "--model",
        &m,
        "--inputs",
        &ds,
        "--out",
        &x.s("never.safetensors"),
        "--validate",
        &missing,
    ]);
    assert!(
        e.contains("--validate") && e.contains("no-such-dataset"),
        "{e}"
    );

    let out = x.s("r.safetensors");
    let err = logged(
        &[
            "infer",
            "--model",
            &run,
            "--inputs",
            &ds,
            "--out",
            &out,
            "--vision",
            "16",
            "--iterations",
            "2",
            "--window",
            "5",
        ],
        "0",
    );
    assert!(
        err.contains("infer: 3/") && err.contains(", sequence 0, window F "),
        "{err}"
    );
    let f = TensorFile::open(Path::new(&out)).unwrap();
    let names: Vec<String> = serde_json::from_str(f.metadata("sequence_names").unwrap()).unwrap();
    assert_eq!(names, ["wiping_650mm_test0"]);
    assert_eq!(f.shape("recon.exteroceptive").unwrap()[2], 32_256);
    let e = fails(&[
        "infer", "--model", &run, "--inputs", &ds, "--out", &out, "--split", "later",
    ]);
    assert!(e.contains("--split later"), "{e}");

    // evaluate: the report with its baselines, then the progress table and the curves.
    let eval = x.s("eval");
    ok(&[
        "evaluate",
        "--model",
        &run,
        "--inputs",
        &ds,
        "--vision",
        "16",
        "--iterations",
        "2",
        "--window",
        "5",
        "--trials",
        "2",
        "--out",
        &eval,
    ]);
    for file in [
        "summary.json",
        "summary.md",
        "per_sequence.csv",
        "per_step.csv",
    ] {
        assert!(x.path("eval").join(file).is_file(), "{file}");
    }
    let plots: Vec<String> = std::fs::read_dir(x.path("eval/plots"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        plots.contains(&"error_wiping_650mm_test0.png".to_string()),
        "{plots:?}"
    );
    assert!(
        plots.contains(&"images_wiping_650mm_test0.png".to_string()),
        "{plots:?}"
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(x.path("eval/summary.json")).unwrap())
            .unwrap();
    assert_eq!(summary["meta"]["model_iteration"], 2);
    assert_eq!(summary["trials"], 2);
    let sources: Vec<&str> = summary["comparisons"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| c["group"] == "v64" && c["scope"] == "all" && c["pixels"] == "all")
        .map(|c| c["baseline"].as_str().unwrap())
        .collect();
    for baseline in ["upsample", "upsample_detail", "nearest", "previous", "mean"] {
        assert!(sources.contains(&baseline), "{baseline}: {sources:?}");
    }
    // The recipe table from a run's validation log and time, and an evaluation.
    let recipe = x.path("recipes/early");
    std::fs::create_dir_all(recipe.join("val-all")).unwrap();
    std::fs::copy(
        x.path("early.validation.csv"),
        recipe.join("run.validation.csv"),
    )
    .unwrap();
    std::fs::copy(x.path("early.log.csv"), recipe.join("run.log.csv")).unwrap();
    std::fs::copy(
        x.path("eval/summary.json"),
        recipe.join("val-all/summary.json"),
    )
    .unwrap();
    let md = ok(&["report", "recipes", &format!("early={}", recipe.display())]);
    let best = pvrnn_eval::validation::best(
        &pvrnn_eval::validation::read_log(&recipe.join("run.validation.csv")).unwrap(),
    )
    .unwrap()
    .clone();
    assert!(
        md.contains(&format!("| early | {} (", best.iteration))
            && md.contains(&format!(
                "**{}",
                pvrnn_eval::report::sig(best.recon_vision_top)
            ))
            && md.contains(" h |"),
        "{md}"
    );
    let e = fails(&["report", "recipes", &format!("none={}", x.s("recipes"))]);
    assert!(e.contains("no run.validation.csv"), "{e}");
    // The results' index: the validation log listed with its best iteration and gate;
    // `--check` passes on the index just written and fails once the files change.
    let index = x.s("recipes/index.md");
    ok(&["report", "index", &x.s("recipes"), "--out", &index]);
    let md = std::fs::read_to_string(&index).unwrap();
    assert!(
        md.contains(&format!(
            "| [early/run.validation.csv](early/run.validation.csv) | {} |",
            pvrnn_eval::validation::read_log(&recipe.join("run.validation.csv"))
                .unwrap()
                .len()
        )) && md.contains(&format!(" | {} | ", best.iteration)),
        "{md}"
    );
    ok(&[
        "report",
        "index",
        &x.s("recipes"),
        "--out",
        &index,
        "--check",
    ]);
    std::fs::copy(
        recipe.join("run.validation.csv"),
        x.path("recipes/early/second.validation.csv"),
    )
    .unwrap();
    let e = fails(&[
        "report",
        "index",
        &x.s("recipes"),
        "--out",
        &index,
        "--check",
    ]);
    assert!(
        e.contains("is not the index of") && e.contains("pvrnn report index"),
        "{e}"
    );
    let table = x.s("progress.md");
    ok(&["report", "table", &eval, "--out", &table]);
    let md = std::fs::read_to_string(&table).unwrap();
    assert!(
        md.contains("### vision 16, proprioception on") && md.contains("| 2 |"),
        "{md}"
    );
    ok(&[
        "report",
        "curves",
        "--log",
        &x.s("run.log.csv"),
        "--out",
        &x.s("curves.png"),
    ]);
    let png = std::fs::read(x.path("curves.png")).unwrap();
    assert!(
        png.starts_with(b"\x89PNG") && png.len() > 10_000,
        "{} bytes",
        png.len()
    );
    // bundle: f16 weights, one runs file per condition, and the card with the evaluation.
    let b = x.s("bundle");
    let err = logged(
        &[
            "bundle",
            "--model",
            &run,
            "--dataset",
            &ds,
            "--out",
            &b,
            "--conditions",
            "all/on,16/off",
            "--evaluation",
            &eval,
            "--machine",
            "the test machine",
        ],
        "0",
    );
    assert!(err.contains(", sequence 0, window F "), "{err}");
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(x.path("bundle/bundle.json")).unwrap())
            .unwrap();
    assert_eq!(
        manifest["runs"],
        serde_json::json!(["runs-all-on.safetensors", "runs-16-off.safetensors"])
    );
    // The explorer's reader (the one shared definition) takes what the CLI wrote.
    let read = pvrnn_dataset::bundle::BundleManifest::parse(
        &std::fs::read(x.path("bundle/bundle.json")).unwrap(),
        "bundle.json",
    )
    .unwrap();
    assert_eq!(read.version, pvrnn_dataset::bundle::BUNDLE_VERSION);
    assert_eq!(read.card.as_ref().and_then(|c| c.iteration), Some(2));
    assert_eq!(manifest["card"]["iteration"], 2);
    assert_eq!(manifest["card"]["training_machine"], "the test machine");
    assert!(manifest["card"]["training_seconds"].as_f64().unwrap() > 0.0);
    assert_eq!(manifest["card"]["evaluations"].as_array().unwrap().len(), 1);
    assert!(
        manifest["card"]["weights"]
            .as_str()
            .unwrap()
            .starts_with("f16 (rounding")
    );
    let shipped = std::fs::metadata(x.path("bundle/model.safetensors"))
        .unwrap()
        .len() as usize;
    let full =
        io::model_to_bytes(&io::load_model(Path::new(&run)).unwrap().weights_only()).unwrap();
    assert!(
        shipped * 10 < full.len() * 6,
        "f16 weights: {shipped} vs {}",
        full.len()
    );
    io::load_model(&x.path("bundle/model.safetensors")).unwrap();
    let readme = std::fs::read_to_string(x.path("bundle/README.md")).unwrap();
    assert!(
        readme.contains("2 iterations") && readme.contains("| recon | v64* | all |"),
        "{readme}"
    );
    let e = fails(&[
        "bundle",
        "--model",
        &run,
        "--dataset",
        &ds,
        "--out",
        &b,
        "--conditions",
        "16",
    ]);
    assert!(e.contains("VISION/PROPRIO"), "{e}");

    // A training log is not an evaluation, and an inputs file is not a dataset folder.
    let e = fails(&["report", "table", &x.s("run.log.csv")]);
    assert!(e.contains("run.log.csv"), "{e}");
    let e = fails(&[
        "evaluate",
        "--model",
        &run,
        "--inputs",
        &x.s("r.safetensors"),
        "--out",
        &eval,
    ]);
    assert!(e.contains("dataset folder"), "{e}");

    // The paper-sized default model does not fit a dataset of other image sizes, and says so.
    let e = fails(&[
        "free-energy",
        "--model",
        &x.s("m.safetensors"),
        "--inputs",
        &x.s("missing-ds"),
    ]);
    assert!(e.contains("missing-ds"), "{e}");
}

#[test]
fn import_reads_recordings_into_a_dataset() {
    let x = Scratch::new();
    let seq = pvrnn_dataset::Sequence {
        info: pvrnn_dataset::SequenceInfo {
            name: "rec".into(),
            file: "rec.safetensors".into(),
            task: "wiping".into(),
            bed_height_mm: None,
            split: pvrnn_dataset::Split::Learn,
            seed: None,
            length: 3,
            subtasks: vec![],
        },
        cameras: 2,
        image_size: 64,
        images: (0..3 * 2 * 64 * 64 * 3).map(|i| (i % 256) as u8).collect(),
        joints: vec![0.1; 3 * 14],
        torques: vec![1.5; 3 * 14],
        subtask: vec![0; 3],
        extra: Vec::new(),
        images_without_robot: None,
    };
    let layout = pvrnn_dataset::import::RecordingLayout::default();
    pvrnn_dataset::import::write_recording(&seq, &layout, &x.path("recordings").join("trial_a"))
        .unwrap();
    let err = logged(
        &["import", "--from", &x.s("recordings"), "--out", &x.s("ds")],
        "0",
    );
    assert!(
        err.contains("import: 0/1 (0.0%), trial_a") && err.contains("import: 1/1 (100.0%)"),
        "{err}"
    );
    let ds = pvrnn_dataset::Dataset::open(&x.path("ds")).unwrap();
    assert_eq!(ds.sequences[0].images, seq.images);
    assert!(x.path("ds").join("previews").join("trial_a.png").is_file());
    std::fs::remove_file(
        x.path("recordings")
            .join("trial_a")
            .join("left")
            .join("000001.png"),
    )
    .unwrap();
    let e = fails(&["import", "--from", &x.s("recordings"), "--out", &x.s("ds2")]);
    assert!(e.contains("frame 1 is missing"), "{e}");
}

/// `pvrnn experiment`: plan + run + report in one command at smoke scale, a second run
/// skips everything, scales never mix, and the cluster scripts come out.
#[test]
fn experiment_plans_runs_and_reports_at_smoke_scale() {
    let x = Scratch::new();
    pvrnn_dataset::synthetic::caresim_like(&[650], 3, 1, 24)
        .unwrap()
        .write(&x.path("ds"))
        .unwrap();
    let (ds, out) = (x.s("ds"), x.s("unc"));
    let e = fails(&["experiment", "uncertainty", "--out", &out]);
    assert!(e.contains("--dataset"), "{e}");
    ok(&[
        "--threads",
        "2",
        "experiment",
        "uncertainty",
        "--scale",
        "smoke",
        "--dataset",
        &ds,
        "--out",
        &out,
    ]);
    let md = std::fs::read_to_string(x.path("unc/report/report.md")).unwrap();
    assert!(
        md.contains("# Experiment: uncertainty (smoke scale)") && md.contains("paired t-tests"),
        "{md}"
    );
    // The networks' logs have `pvrnn train`'s columns (terms per modality and module).
    let log = std::fs::read_to_string(x.path("unc/networks/smoke-train-net0.log.csv")).unwrap();
    assert!(
        log.starts_with(pvrnn_eval::training_log::HEADER) && log.lines().count() > 2,
        "{log}"
    );
    let before = std::fs::metadata(x.path("unc/networks/smoke-train-net0.safetensors"))
        .unwrap()
        .modified()
        .unwrap();
    let again = pvrnn(&[
        "experiment",
        "uncertainty",
        "--scale",
        "smoke",
        "--out",
        &out,
    ]);
    assert!(again.status.success());
    assert!(
        !String::from_utf8_lossy(&again.stderr).contains("started"),
        "nothing left to run"
    );
    assert_eq!(
        std::fs::metadata(x.path("unc/networks/smoke-train-net0.safetensors"))
            .unwrap()
            .modified()
            .unwrap(),
        before
    );
    // A network whose prior sigma blows up (log sigma = 1000 x the state): its inference
    // runs diverge beyond repair, are recorded as such, and the report leaves them out
    // instead of the experiment failing.
    let net1 = x.path("unc/networks/smoke-train-net1.safetensors");
    let mut broken = io::load_checkpoint(&net1).unwrap();
    broken.state_mut().0.params.modules[3]
        .w_prior_sigma
        .data_mut()
        .fill(1000.0);
    io::save_checkpoint(&net1, &mut broken, None).unwrap();
    for entry in std::fs::read_dir(x.path("unc/results")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "safetensors") {
            std::fs::remove_file(path).unwrap();
        }
    }
    let rerun = pvrnn(&[
        "experiment",
        "uncertainty",
        "--scale",
        "smoke",
        "--out",
        &out,
    ]);
    let log = String::from_utf8_lossy(&rerun.stderr);
    assert!(rerun.status.success(), "{log}");
    assert!(log.contains("diverged beyond repair at step"), "{log}");
    let md = std::fs::read_to_string(x.path("unc/report/report.md")).unwrap();
    assert!(
        md.contains("**Diverged**") && md.contains("network 1 on") && !md.contains("network 0 on"),
        "{md}"
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(x.path("unc/report/summary.json")).unwrap())
            .unwrap();
    let diverged = summary["diverged"].as_array().unwrap();
    assert!(
        !diverged.is_empty() && diverged.iter().all(|d| d["network"] == 1),
        "{summary}"
    );
    // The tidy table keeps every run; a diverged one says where and has no scores, and
    // every row says what computed it.
    let rows = csv_columns(
        &x.path("unc/report/trials.csv"),
        &["diverged_at_step", "error_proprio", "backend"],
    );
    let (at_step, error, backend) = (0, 1, 2);
    let flagged = rows.iter().filter(|r| !r[at_step].is_empty()).count();
    assert!(
        rows.iter()
            .all(|r| r[at_step].is_empty() != r[error].is_empty()),
        "a diverged run has no scores, every other run has"
    );
    assert!(
        rows.iter().all(|r| r[backend].starts_with("cpu, ")),
        "backend column"
    );
    let trials = format!("{} rows", rows.len());
    assert_eq!(flagged, diverged.len(), "{trials}");
    // A second experiment sharing the networks folder trains nothing.
    let shared = x.s("shared");
    ok(&[
        "experiment",
        "uncertainty",
        "--dataset",
        &ds,
        "--out",
        &x.s("u1"),
        "--networks",
        &shared,
    ]);
    let second = pvrnn(&[
        "experiment",
        "robustness",
        "--dataset",
        &ds,
        "--out",
        &x.s("r1"),
        "--networks",
        &shared,
        "--network",
        "0",
    ]);
    assert!(second.status.success());
    let log = String::from_utf8_lossy(&second.stderr);
    // Only network 0's jobs ran (`--network`), and the report of what is done came out.
    assert!(
        log.contains("train-net0")
            && !log.contains("iteration 1/")
            && log.contains("infer-net0")
            && !log.contains("-net1"),
        "{log}"
    );
    assert!(x.path("r1/report/report.md").is_file());
    // Hierarchy on data with robot-free renders scores the hidden pixels beside baselines.
    ok(&[
        "experiment",
        "hierarchy",
        "--dataset",
        &ds,
        "--out",
        &x.s("h1"),
        "--networks",
        &shared,
    ]);
    let md = std::fs::read_to_string(x.path("h1/report/report.md")).unwrap();
    assert!(
        md.contains("## Occlusion") && md.contains("| last seen vs hidden body |"),
        "{md}"
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(x.path("h1/report/summary.json")).unwrap())
            .unwrap();
    assert!(
        summary.to_string().contains("model vs hidden body"),
        "{summary}"
    );
    // Networks learned on one dataset are not reused for another.
    let mut other = pvrnn_dataset::synthetic::caresim_like(&[650], 3, 1, 24).unwrap();
    other.manifest.source = "synthetic (matched variability)".into();
    other.write(&x.path("ds-other")).unwrap();
    let e = fails(&[
        "experiment",
        "uncertainty",
        "--dataset",
        &x.s("ds-other"),
        "--out",
        &x.s("u2"),
        "--networks",
        &shared,
    ]);
    assert!(
        e.contains("learned other data") && e.contains("another --networks"),
        "{e}"
    );
    let e = fails(&[
        "experiment",
        "uncertainty",
        "--scale",
        "paper",
        "--out",
        &out,
    ]);
    assert!(e.contains("smoke") && e.contains("another --out"), "{e}");
    // Without --scale, an existing plan's own scale.
    ok(&["experiment", "uncertainty", "--out", &out, "--report"]);
    ok(&[
        "experiment",
        "uncertainty",
        "--scale",
        "smoke",
        "--out",
        &out,
        "--emit",
        "slurm",
    ]);
    let submit = std::fs::read_to_string(x.path("unc/slurm/submit.sh")).unwrap();
    assert!(
        submit.contains("report.sbatch") && !submit.contains("--array"),
        "all done: {submit}"
    );
    let e = fails(&[
        "experiment",
        "uncertainty",
        "--scale",
        "smoke",
        "--out",
        &out,
        "--job",
        "999",
    ]);
    assert!(e.contains("999"), "{e}");
}

/// `pvrnn report drive`: the episodes under a folder as the success table (one row per
/// task, condition and controller; the Panda's joint speeds are a condition of their own)
/// and, with `--figure`, as bars with their Wilson intervals (PNG and SVG).
#[test]
fn the_drive_report_tables_and_draws_the_episodes() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("episodes");
    for (name, limit) in [("scripted", "scripted"), ("panda", "panda")] {
        let out = root.join(name);
        ok(&[
            "--threads",
            "1",
            "drive",
            "--controller",
            "mean-trajectory",
            "--task",
            "wiping",
            "--bed-height",
            "650",
            "--revision",
            "2",
            "--speed-limit",
            limit,
            "--out",
            out.to_str().unwrap(),
        ]);
    }
    let table = dir.path().join("table.md");
    let figure = dir.path().join("success.png");
    ok(&[
        "report",
        "drive",
        root.to_str().unwrap(),
        "--out",
        table.to_str().unwrap(),
        "--figure",
        figure.to_str().unwrap(),
    ]);
    let table = std::fs::read_to_string(table).unwrap();
    let rows: Vec<&str> = table
        .lines()
        .filter(|l| l.starts_with("| wiping"))
        .collect();
    assert_eq!(rows.len(), 2, "{table}");
    assert!(
        rows[0].starts_with("| wiping | Panda's joint speeds | mean-trajectory | 1 |"),
        "{table}"
    );
    assert!(
        rows[1].starts_with("| wiping | as learned | mean-trajectory | 1 |"),
        "{table}"
    );
    let png = std::fs::read(&figure).unwrap();
    assert!(
        png.starts_with(b"\x89PNG") && png.len() > 10_000,
        "{} bytes",
        png.len()
    );
    let svg = std::fs::read_to_string(figure.with_extension("svg")).unwrap();
    assert!(
        svg.contains("W: Panda") && svg.contains("W: learned"),
        "{svg}"
    );
    // Each folder under the root as a network: the statistics over networks come first.
    let over = ok(&["report", "drive", root.to_str().unwrap(), "--networks"]);
    assert!(over.starts_with("Over networks"), "{over}");
    assert!(
        over.contains("| wiping | as learned | mean-trajectory | 1 | 1 |"),
        "{over}"
    );
    assert!(over.contains("Every episode"), "{over}");
    // A folder without episodes is an error that says so.
    let err = pvrnn(&["report", "drive", dir.path().join("none").to_str().unwrap()]);
    assert!(!err.status.success());
    // A vision drop that cannot be: said before anything is driven.
    let out = dir.path().join("refused");
    let out = out.to_str().unwrap();
    for (drop, says) in [
        ("10", "expected FROM:LEVELS"),
        ("10:0", "observes no vision"),
    ] {
        let err = fails(&[
            "drive",
            "--controller",
            "mean-trajectory",
            "--task",
            "wiping",
            "--drop-vision",
            drop,
            "--out",
            out,
        ]);
        assert!(err.contains(says), "--drop-vision {drop}: {err}");
    }
}
