// Helpers of the output layers' kernels (prepended to each of them by `gpu/output_kernels.rs`).

// tanh that stays finite for any input (some implementations overflow exp(2a)).
fn tanh_safe(a: f32) -> f32 {
    return tanh(clamp(a, -15.0, 15.0));
}

// A vec4's components added in a fixed order, the same in every kernel.
fn sum4(v: vec4<f32>) -> f32 {
    return (v.x + v.y) + (v.z + v.w);
}
