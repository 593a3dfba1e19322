// Adds the column splits' partial input gradients and row losses of one chunk, in split
// order (so results do not depend on scheduling), into the rows of the whole batch.

const HV: u32 = {{HV}}u;

struct Params {
    rows: u32,
    splits: u32,
    row_offset: u32,
    _pad: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> part_in: array<vec4<f32>>;      // [splits, rows, HV]
@group(0) @binding(2) var<storage, read> part_loss: array<f32>;          // [splits, rows]
@group(0) @binding(3) var<storage, read_write> grad_in: array<vec4<f32>>; // [all rows, HV]
@group(0) @binding(4) var<storage, read_write> row_loss: array<f32>;     // [all rows]

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if (i >= p.rows * HV) {
        return;
    }
    // Four loads in flight before their four adds (the same order of sums).
    let stride = p.rows * HV;
    var a = vec4<f32>(0.0);
    var s = 0u;
    for (; s + 4u <= p.splits; s += 4u) {
        //#unroll K 4
        let v{K} = part_in[(s + {K}u) * stride + i];
        //#end
        //#unroll K 4
        a += v{K};
        //#end
    }
    for (; s < p.splits; s++) {
        a += part_in[s * stride + i];
    }
    grad_in[p.row_offset * HV + i] = a;
    if (i % HV == 0u) {
        let r = i / HV;
        var l = 0.0;
        var t = 0u;
        for (; t + 4u <= p.splits; t += 4u) {
            //#unroll K 4
            let l{K} = part_loss[(t + {K}u) * p.rows + r];
            //#end
            //#unroll K 4
            l += l{K};
            //#end
        }
        for (; t < p.splits; t++) {
            l += part_loss[t * p.rows + r];
        }
        row_loss[p.row_offset + r] = l;
    }
}
