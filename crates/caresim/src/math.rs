//! The transcendental functions caresim calls, from the pure-Rust `libm` crate rather than
//! the platform's C library: glibc picks its `sin`/`cos`/`log` implementation per CPU
//! feature set (FMA or not) and none is correctly rounded, so the same seed could write
//! other bytes on another machine. `libm` is plain Rust arithmetic, the same on every CPU.
//! (`sqrt` is correctly rounded everywhere; glam's own trigonometry goes through `libm`
//! by its `libm` feature.) `clippy.toml` beside this crate forbids the std methods.

pub(crate) fn sin(x: f64) -> f64 {
    libm::sin(x)
}

pub(crate) fn cos(x: f64) -> f64 {
    libm::cos(x)
}

pub(crate) fn tan(x: f64) -> f64 {
    libm::tan(x)
}

pub(crate) fn ln(x: f64) -> f64 {
    libm::log(x)
}
