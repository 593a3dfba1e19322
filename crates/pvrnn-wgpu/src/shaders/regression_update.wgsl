// One of online inference's updates of the window's adaptive variables, on the device so
// that a step's updates run in one submission: after the recurrence backward has written
// d F / d a into `back`, one thread per (step, module unit) checks that this update's
// terms are finite (its gradients, its KL term, and for the step's first unit the
// read-outs' row losses), applies RAdam to a_mu and a_sigma where the recurrence reads
// them (the inputs' a slots), and writes the next update's eps into the eps slot.
//
// `table` holds, as 32-bit words: a header, the modules' offsets, each update's RAdam
// scalars (f32 bits) and each update's eps (f32 bits), see `regression.rs`.
//   header: 0 len, 1 sum_z, 2 init stride, 3 input stride, 4 back stride, 5 record stride,
//           6 updates, 7 extero row losses bound, 8 proprio row losses bound
//   module m at 16 + 8 m: z, offset among the step's units, input, back, KL row in record
//   update u's scalars at 48 + 12 u: rectified, b1, b2, 1-b1, 1-b2, wd, eps, sqrt_bias2, lr
//   eps at 48 + 12 updates: [updates, len, sum_z]
// `moments`: m then v, each a_mu then a_sigma, `[len, sum_z]`.

struct Params {
    update: u32,
    count: u32,       // len x sum_z threads
    groups_x: u32,    // workgroups per row of the dispatch grid
    _pad: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> table: array<u32>;
@group(0) @binding(2) var<storage, read> back: array<f32>;
@group(0) @binding(3) var<storage, read> record: array<f32>;
@group(0) @binding(4) var<storage, read> rows_e: array<f32>;
@group(0) @binding(5) var<storage, read> rows_p: array<f32>;
@group(0) @binding(6) var<storage, read_write> inputs: array<f32>;
@group(0) @binding(7) var<storage, read_write> moments: array<f32>;
@group(0) @binding(8) var<storage, read_write> flags: array<u32>;

// Infinite or NaN, by the exponent bits (WGSL may assume arithmetic never produces them,
// so comparisons cannot be trusted to find them).
fn bad(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) == 0x7f800000u;
}

fn scalar(u: u32, k: u32) -> f32 {
    return bitcast<f32>(table[48u + 12u * u + k]);
}

// RAdam on one value (pvrnn-core's `RAdam::apply`, as `radam.wgsl`); `at` its input slot,
// `mo` its index in the first moment.
fn radam(at: u32, mo: u32, g: f32) {
    let u = p.update;
    let rectified = table[48u + 12u * u];
    let x = inputs[at];
    let gd = fma(scalar(u, 5u), x, g);
    let mi = fma(scalar(u, 1u), moments[mo], scalar(u, 3u) * gd);
    let vo = mo + 2u * p.count;
    let vi = fma(scalar(u, 2u), moments[vo], scalar(u, 4u) * gd * gd);
    moments[mo] = mi;
    moments[vo] = vi;
    if (rectified != 0u) {
        inputs[at] = x - scalar(u, 8u) * mi * scalar(u, 7u) / (sqrt(vi) + scalar(u, 6u));
    } else {
        inputs[at] = x - scalar(u, 8u) * mi;
    }
}

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let i = (wg.y * p.groups_x + wg.x) * 64u + t;
    if (i >= p.count) {
        return;
    }
    let sum_z = table[1];
    let step = i / sum_z;
    let c = i % sum_z;
    var m = 0u;
    for (var k = 1u; k < 4u; k++) {
        if (c >= table[16u + 8u * k + 1u]) {
            m = k;
        }
    }
    let base = 16u + 8u * m;
    let z = table[base];
    let j = c - table[base + 1u];
    let back_at = step * table[4] + table[base + 3u] + j;
    let g_mu = back[back_at];
    let g_sigma = back[back_at + z];
    var diverged = bad(g_mu) || bad(g_sigma) || bad(record[step * table[5] + table[base + 4u] + j]);
    if (c == 0u) {
        diverged = diverged || (table[7] != 0u && bad(rows_e[step]))
            || (table[8] != 0u && bad(rows_p[step]));
    }
    if (diverged) {
        flags[p.update] = 1u;
    }
    let at = table[2] + step * table[3] + table[base + 2u] + j;
    radam(at, i, g_mu);
    radam(at + z, p.count + i, g_sigma);
    let updates = table[6];
    if (p.update + 1u < updates) {
        let eps_at = 48u + 12u * updates + (p.update + 1u) * p.count + i;
        inputs[at + 2u * z] = bitcast<f32>(table[eps_at]);
    }
}
