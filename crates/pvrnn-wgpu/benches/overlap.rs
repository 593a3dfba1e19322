//! Does the GPU run two independent dispatches at once under wgpu? The question behind the
//! one-network target (docs/gpu.md, "Roofline"): the recurrence is a chain of dependent
//! steps in one workgroup per window (18 at the paper's scale), which leaves most of a GPU
//! idle for about 4.5 ms of a 10 ms iteration, while the read-outs' weight gradients (about
//! 1.2 ms) need nothing the recurrence's backward pass computes. They could share the
//! device only if wgpu puts no barrier between them, that is if the second dispatch uses
//! no buffer in a state the first one left it in that needs a transition (wgpu-core's
//! per-dispatch usage scopes), and if the driver then runs them side by side.
//!
//! Two synthetic kernels of those shapes, not the model's: a *chain* (few workgroups, many
//! steps, a barrier between phases, short dependent dot products) and *tiles* (many
//! workgroups of independent multiply-adds). Each case is one compute pass of one
//! submission, timed by the device (timestamps at the pass's start and end, where the
//! adapter has them) and by the host (submit to idle):
//!
//! - `chain` and `tiles` alone;
//! - `chain, tiles`: both, no buffer in common, so no barrier between them;
//! - `tiles, chain`: the same in the other order;
//! - `chain, tiles, barrier`: both, with the tiles binding the chain's output read-write
//!   too (never written), so wgpu puts a barrier between them: the sum, for comparison.
//!
//! The cases alternate within each round. The result line says how much of the shorter
//! kernel's time the overlap hid: as much as the barrier case (the fixed costs of a run,
//! counted twice in the sum of the two alone) means the device ran them one after the
//! other. Every
//! case's outputs are compared with those of the kernels alone (bit for bit), so a case
//! that skipped work fails. On a CPU Vulkan device (lavapipe) nothing overlaps; it checks
//! that the benchmark runs.
//!
//! `cargo bench -p pvrnn-wgpu --bench overlap` (sized for an H100 or H200: the chain about
//! the recurrence's backward, the tiles about the weight gradients); `-- --quick` for a CPU
//! device (`scripts/test.sh` runs it so on lavapipe); `WGPU_ADAPTER_NAME` / `WGPU_BACKEND`
//! pick the adapter as for the backend; without one it fails unless `PVRNN_SKIP_WGPU` is set.
#![allow(clippy::unwrap_used)] // a benchmark: a failed unwrap is a failed run

mod common;
use common::values;

use std::time::Instant;

use wgpu::util::DeviceExt;

/// The kernels' sizes.
struct Shape {
    /// Chain: workgroups (windows), steps, barrier phases per step, dot-product length.
    chain_groups: u32,
    steps: u32,
    phases: u32,
    dot: u32,
    /// Tiles: workgroups, and loop trips (each 32 multiply-adds per thread).
    tile_groups: u32,
    trips: u32,
    /// Rounds of all cases, and timed submissions per case per round.
    rounds: usize,
    repeats: usize,
}

const CHAIN_WIDTH: u32 = 384;
const TILE_WIDTH: u32 = 256;
const TABLE: u32 = 1024; // vec4s the tiles read from (cached)

fn chain_source(s: &Shape) -> String {
    format!(
        "const WIDTH: u32 = {CHAIN_WIDTH}u;
const STEPS: u32 = {steps}u;
const PHASES: u32 = {phases}u;
const DOT: u32 = {dot}u;
@group(0) @binding(0) var<storage, read> weights: array<f32>;
@group(0) @binding(1) var<storage, read_write> state: array<f32>;
var<workgroup> shared_x: array<f32, WIDTH>;
@compute @workgroup_size(WIDTH)
fn main(@builtin(local_invocation_index) i: u32, @builtin(workgroup_id) g: vec3<u32>) {{
    var x = state[g.x * WIDTH + i];
    for (var t = 0u; t < STEPS; t++) {{
        for (var p = 0u; p < PHASES; p++) {{
            shared_x[i] = x;
            workgroupBarrier();
            var sum = 0.0;
            for (var k = 0u; k < DOT; k++) {{
                sum = fma(weights[(p * WIDTH + i) * DOT + k], shared_x[(i + 7u * k + 1u) % WIDTH], sum);
            }}
            workgroupBarrier();
            x = tanh(0.05 * sum + 0.9 * x);
        }}
    }}
    state[g.x * WIDTH + i] = x;
}}
",
        steps = s.steps,
        phases = s.phases,
        dot = s.dot,
    )
}

fn tiles_source(s: &Shape) -> String {
    format!(
        "const TRIPS: u32 = {trips}u;
@group(0) @binding(0) var<storage, read> table: array<vec4<f32>>;
@group(0) @binding(1) var<storage, read_write> out: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> shared_with: array<f32>;
@compute @workgroup_size({TILE_WIDTH})
fn main(@builtin(global_invocation_id) id: vec3<u32>, @builtin(local_invocation_index) i: u32) {{
    var a0 = table[i % {TABLE}u];
    var a1 = table[(i + 1u) % {TABLE}u];
    var a2 = table[(i + 2u) % {TABLE}u];
    var a3 = table[(i + 3u) % {TABLE}u];
    var a4 = table[(i + 4u) % {TABLE}u];
    var a5 = table[(i + 5u) % {TABLE}u];
    var a6 = table[(i + 6u) % {TABLE}u];
    var a7 = table[(i + 7u) % {TABLE}u];
    let decay = vec4<f32>(0.999);
    for (var k = 0u; k < TRIPS; k++) {{
        let v = table[(i + k) % {TABLE}u];
        a0 = fma(a0, decay, v);
        a1 = fma(a1, decay, v);
        a2 = fma(a2, decay, v);
        a3 = fma(a3, decay, v);
        a4 = fma(a4, decay, v);
        a5 = fma(a5, decay, v);
        a6 = fma(a6, decay, v);
        a7 = fma(a7, decay, v);
    }}
    let total = a0 + a1 + a2 + a3 + a4 + a5 + a6 + a7;
    out[id.x] = total;
    // Never true (the table's values are within 1 and the sums bounded): it keeps the
    // binding in use, so that binding the chain's output here makes wgpu put a barrier.
    if (total.x == -12345.0) {{
        shared_with[0] = total.y;
    }}
}}
",
        trips = s.trips,
    )
}

struct Probe {
    device: wgpu::Device,
    queue: wgpu::Queue,
    chain: wgpu::ComputePipeline,
    tiles: wgpu::ComputePipeline,
    chain_start: Vec<f32>,
    state: wgpu::Buffer,
    out: wgpu::Buffer,
    chain_binding: wgpu::BindGroup,
    tiles_alone: wgpu::BindGroup,
    tiles_sharing: wgpu::BindGroup,
    timestamps: Option<(wgpu::QuerySet, wgpu::Buffer, wgpu::Buffer)>,
    shape: Shape,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Step {
    Chain,
    Tiles,
    TilesSharing,
}

const CASES: [(&str, &[Step]); 5] = [
    ("chain", &[Step::Chain]),
    ("tiles", &[Step::Tiles]),
    ("chain, tiles", &[Step::Chain, Step::Tiles]),
    ("tiles, chain", &[Step::Tiles, Step::Chain]),
    ("chain, tiles, barrier", &[Step::Chain, Step::TilesSharing]),
];

impl Probe {
    fn new(shape: Shape) -> Option<Self> {
        let mut descriptor = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        descriptor.backends = wgpu::Backends::from_env().unwrap_or(wgpu::Backends::PRIMARY);
        let instance = wgpu::Instance::new(descriptor);
        let adapter = match pollster::block_on(wgpu::util::initialize_adapter_from_env_or_default(
            &instance, None,
        )) {
            Ok(a) => a,
            // As the backend's tests: no adapter fails, unless told to skip.
            Err(e) if std::env::var_os("PVRNN_SKIP_WGPU").is_some() => {
                eprintln!("skipped (PVRNN_SKIP_WGPU): {e}");
                return None;
            }
            Err(e) => panic!("no GPU adapter ({e}); PVRNN_SKIP_WGPU=1 skips"),
        };
        let info = adapter.get_info();
        println!(
            "adapter: {} ({:?}, {} {})",
            info.name, info.backend, info.driver, info.driver_info
        );
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("overlap probe"),
            required_limits: adapter.limits(),
            required_features: adapter.features() & wgpu::Features::TIMESTAMP_QUERY,
            ..Default::default()
        }))
        .unwrap();
        let pipeline = |label: &str, source: String| {
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: None,
                module: &module,
                entry_point: Some("main"),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        let chain = pipeline("chain", chain_source(&shape));
        let tiles = pipeline("tiles", tiles_source(&shape));
        let storage = |label: &str, data: &[f32]| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytemuck::cast_slice(data),
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_SRC
                    | wgpu::BufferUsages::COPY_DST,
            })
        };
        let weights = storage(
            "weights",
            &values((shape.phases * CHAIN_WIDTH * shape.dot) as usize, 1)
                .iter()
                .map(|w| w / shape.dot as f32)
                .collect::<Vec<_>>(),
        );
        let chain_start = values((shape.chain_groups * CHAIN_WIDTH) as usize, 2);
        let state = storage("state", &chain_start);
        let table = storage("table", &values(4 * TABLE as usize, 3));
        let out = storage(
            "out",
            &vec![0.0; 4 * (shape.tile_groups * TILE_WIDTH) as usize],
        );
        let unshared = storage("unshared", &[0.0; 4]);
        let group = |pipeline: &wgpu::ComputePipeline, buffers: &[&wgpu::Buffer]| {
            let entries: Vec<_> = buffers
                .iter()
                .enumerate()
                .map(|(i, b)| wgpu::BindGroupEntry {
                    binding: i as u32,
                    resource: b.as_entire_binding(),
                })
                .collect();
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: None,
                layout: &pipeline.get_bind_group_layout(0),
                entries: &entries,
            })
        };
        let chain_binding = group(&chain, &[&weights, &state]);
        let tiles_alone = group(&tiles, &[&table, &out, &unshared]);
        let tiles_sharing = group(&tiles, &[&table, &out, &state]);
        let timestamps = device
            .features()
            .contains(wgpu::Features::TIMESTAMP_QUERY)
            .then(|| {
                let queries = device.create_query_set(&wgpu::QuerySetDescriptor {
                    label: Some("pass"),
                    ty: wgpu::QueryType::Timestamp,
                    count: 2,
                });
                let buffer = |usage| {
                    device.create_buffer(&wgpu::BufferDescriptor {
                        label: None,
                        size: 16,
                        usage,
                        mapped_at_creation: false,
                    })
                };
                (
                    queries,
                    buffer(wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC),
                    buffer(wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST),
                )
            });
        Some(Self {
            device,
            queue,
            chain,
            tiles,
            chain_start,
            state,
            out,
            chain_binding,
            tiles_alone,
            tiles_sharing,
            timestamps,
            shape,
        })
    }

    /// Runs `steps` in one pass of one submission from the chain's starting state and the
    /// tiles' output cleared (so that a skipped dispatch shows); returns (device seconds
    /// if timed, host seconds).
    fn run(&self, steps: &[Step]) -> (Option<f64>, f64) {
        let mut clear = self.device.create_command_encoder(&Default::default());
        clear.clear_buffer(&self.out, 0, None);
        self.queue
            .write_buffer(&self.state, 0, bytemuck::cast_slice(&self.chain_start));
        self.queue.submit([clear.finish()]);
        self.wait();
        let started = Instant::now();
        let mut encoder = self.device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: None,
                timestamp_writes: self.timestamps.as_ref().map(|(queries, _, _)| {
                    wgpu::ComputePassTimestampWrites {
                        query_set: queries,
                        beginning_of_pass_write_index: Some(0),
                        end_of_pass_write_index: Some(1),
                    }
                }),
            });
            for step in steps {
                match step {
                    Step::Chain => {
                        pass.set_pipeline(&self.chain);
                        pass.set_bind_group(0, &self.chain_binding, &[]);
                        pass.dispatch_workgroups(self.shape.chain_groups, 1, 1);
                    }
                    Step::Tiles | Step::TilesSharing => {
                        pass.set_pipeline(&self.tiles);
                        let group = if *step == Step::Tiles {
                            &self.tiles_alone
                        } else {
                            &self.tiles_sharing
                        };
                        pass.set_bind_group(0, group, &[]);
                        pass.dispatch_workgroups(self.shape.tile_groups, 1, 1);
                    }
                }
            }
        }
        if let Some((queries, resolved, staging)) = &self.timestamps {
            encoder.resolve_query_set(queries, 0..2, resolved, 0);
            encoder.copy_buffer_to_buffer(resolved, 0, staging, 0, 16);
        }
        self.queue.submit([encoder.finish()]);
        self.wait();
        let host = started.elapsed().as_secs_f64();
        let device = self.timestamps.as_ref().map(|(_, _, staging)| {
            let ticks: Vec<u64> = bytemuck::pod_collect_to_vec(&self.read(staging));
            ticks[1].saturating_sub(ticks[0]) as f64
                * f64::from(self.queue.get_timestamp_period())
                * 1e-9
        });
        (device, host)
    }

    fn wait(&self) {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .unwrap();
    }

    fn read(&self, buffer: &wgpu::Buffer) -> Vec<u8> {
        let staging = if buffer.usage().contains(wgpu::BufferUsages::MAP_READ) {
            buffer.clone()
        } else {
            let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: None,
                size: buffer.size(),
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let mut encoder = self.device.create_command_encoder(&Default::default());
            encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, buffer.size());
            self.queue.submit([encoder.finish()]);
            staging
        };
        staging
            .slice(..)
            .map_async(wgpu::MapMode::Read, |r| r.unwrap());
        self.wait();
        let bytes = staging.slice(..).get_mapped_range().unwrap().to_vec();
        staging.unmap();
        bytes
    }

    /// The chain's and the tiles' outputs after the last run.
    fn outputs(&self) -> (Vec<u8>, Vec<u8>) {
        (self.read(&self.state), self.read(&self.out))
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let shape = if quick {
        Shape {
            chain_groups: 2,
            steps: 20,
            phases: 4,
            dot: 30,
            tile_groups: 64,
            trips: 64,
            rounds: 2,
            repeats: 2,
        }
    } else {
        // About the paper's scale on an H200: 18 windows of 300 steps with 8 phases; the
        // tiles' 4,096 x 256 threads x 600 trips x 32 multiply-adds are 40 GFLOP.
        Shape {
            chain_groups: 18,
            steps: 300,
            phases: 8,
            dot: 30,
            tile_groups: 4096,
            trips: 600,
            rounds: 5,
            repeats: 4,
        }
    };
    let Some(probe) = Probe::new(shape) else {
        return;
    };
    let s = &probe.shape;
    println!(
        "chain: {} workgroups of {CHAIN_WIDTH}, {} steps x {} phases, dot products of {}; tiles: {} workgroups of {TILE_WIDTH}, {:.1} GFLOP; {} rounds x {} runs per case; {}",
        s.chain_groups,
        s.steps,
        s.phases,
        s.dot,
        s.tile_groups,
        f64::from(s.tile_groups * TILE_WIDTH) * f64::from(s.trips) * 64.0 * 1e-9,
        s.rounds,
        s.repeats,
        if probe.timestamps.is_some() {
            "device timestamps"
        } else {
            "no timestamps: host times only"
        },
    );

    // The kernels alone give the reference outputs (and warm the pipelines).
    probe.run(&[Step::Chain]);
    let chain_alone = probe.outputs().0;
    probe.run(&[Step::Tiles]);
    let reference = (chain_alone, probe.outputs().1);
    let mut device: Vec<Vec<f64>> = vec![Vec::new(); CASES.len()];
    let mut host: Vec<Vec<f64>> = vec![Vec::new(); CASES.len()];
    for _ in 0..s.rounds {
        for (case, (name, steps)) in CASES.iter().enumerate() {
            for _ in 0..s.repeats {
                let (d, h) = probe.run(steps);
                device[case].extend(d);
                host[case].push(h);
            }
            let (chain, tiles) = probe.outputs();
            if steps.contains(&Step::Chain) {
                assert!(
                    chain == reference.0,
                    "{name}: the chain's output differs from the chain's alone"
                );
            }
            if steps.iter().any(|s| *s != Step::Chain) {
                assert!(
                    tiles == reference.1,
                    "{name}: the tiles' output differs from the tiles' alone"
                );
            }
        }
    }
    let medians = |times: &[Vec<f64>]| -> Option<Vec<f64>> {
        times
            .iter()
            .all(|t| !t.is_empty())
            .then(|| times.iter().cloned().map(median).collect())
    };
    for (what, times) in [("device", medians(&device)), ("host", medians(&host))] {
        let Some(t) = times else { continue };
        for ((name, _), ms) in CASES.iter().zip(&t) {
            println!("{what}: {name:<22} {:8.3} ms (median)", ms * 1e3);
        }
        // Each run's fixed costs are in both kernels' times alone, so even one after the
        // other a case hides a little: the barrier case says how much.
        let (chain, tiles) = (t[0], t[1]);
        let shorter = chain.min(tiles);
        for (case, name) in [
            (2, "chain, tiles"),
            (3, "tiles, chain"),
            (4, "chain, tiles, barrier"),
        ] {
            println!(
                "{what}: {name}: {:.3} ms against {:.3} one after the other: {:.0}% of the shorter kernel's time hidden",
                t[case] * 1e3,
                (chain + tiles) * 1e3,
                100.0 * (chain + tiles - t[case]) / shorter,
            );
        }
    }
}
