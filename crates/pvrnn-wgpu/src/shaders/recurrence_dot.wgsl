// A recurrence kernel's dot product, instanced per pair of arrays (`gpu/recurrence_kernels.rs`:
// DOT is the function's name, WEIGHTS the weights' binding, VALUES the workgroup array it reads).
// acc plus the sum over i < n of WEIGHTS[w_at + i * w_step] * VALUES[x_at + i], added in
// i's order (the CPU's). {{LOADS}} pairs of loads are issued before their multiply-adds: a
// step's phases are chains of dependent loads, and this makes a 30-long sum 4 round trips
// at 8. In the last batch the loads past n - 1 read element n - 1 again and their
// multiply-adds are skipped (`select` keeps acc bit for bit), so every batch is whole.
fn DOT(acc_in: f32, w_at: u32, w_step: u32, x_at: u32, n: u32) -> f32 {
    var acc = acc_in;
    for (var i = 0u; i < n; i += {{LOADS}}u) {
        //#unroll K {{LOADS}}
        let k{K} = min(i + {K}u, n - 1u);
        let w{K} = WEIGHTS[w_at + k{K} * w_step];
        let x{K} = VALUES[x_at + k{K}];
        //#end
        //#unroll K {{LOADS}}
        acc = select(acc, fma(w{K}, x{K}, acc), i + {K}u < n);
        //#end
    }
    return acc;
}
