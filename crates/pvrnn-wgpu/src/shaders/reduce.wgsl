// Adds the column groups' partial input gradients and row losses of one chunk, in group
// order (so results do not depend on scheduling), into the rows of the whole batch.

const HL: u32 = {{HL}}u;

struct Params {
    rows: u32,
    groups: u32,
    row_offset: u32,
    _pad: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> part_in: array<f32>;     // [groups, rows, HL]
@group(0) @binding(2) var<storage, read> part_loss: array<f32>;   // [groups, rows]
@group(0) @binding(3) var<storage, read_write> grad_in: array<f32>;  // [all rows, HL]
@group(0) @binding(4) var<storage, read_write> row_loss: array<f32>; // [all rows]

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if (i >= p.rows * HL) {
        return;
    }
    var a = 0.0;
    for (var g = 0u; g < p.groups; g++) {
        a += part_in[g * p.rows * HL + i];
    }
    grad_in[p.row_offset * HL + i] = a;
    if (i % HL == 0u) {
        let r = i / HL;
        var l = 0.0;
        for (var g = 0u; g < p.groups; g++) {
            l += part_loss[g * p.rows + r];
        }
        row_loss[p.row_offset + r] = l;
    }
}
