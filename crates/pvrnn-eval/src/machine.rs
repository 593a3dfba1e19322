//! Where a result was computed, in words (every report and validation row records it):
//! the CPU's name and widest vector extension, its cores, and the worker threads used.

/// E.g. `AMD EPYC (AVX2), 2 cores, 1 thread`. Reads `/proc/cpuinfo` on Linux; elsewhere
/// the architecture's name.
pub fn describe(threads: usize) -> String {
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|info| cpu_name(&info))
        .unwrap_or_else(|| std::env::consts::ARCH.to_string());
    format!(
        "{cpu}, {cores} core{}, {threads} thread{}",
        if cores == 1 { "" } else { "s" },
        if threads == 1 { "" } else { "s" }
    )
}

/// [`describe`] with the worker threads of the current rayon pool (the threads a run
/// computes with).
pub fn here() -> String {
    describe(rayon::current_num_threads())
}

/// The first processor's model name with its widest SIMD extension, from `/proc/cpuinfo`.
fn cpu_name(info: &str) -> Option<String> {
    let field = |key: &str| {
        info.lines()
            .find(|l| l.split(':').next().is_some_and(|k| k.trim() == key))
            .and_then(|l| l.split_once(':'))
            .map(|(_, v)| v.trim().to_string())
    };
    let name = field("model name")?;
    let flags = field("flags").unwrap_or_default();
    let has = |f: &str| flags.split_whitespace().any(|x| x == f);
    let simd = if has("avx512f") {
        Some("AVX-512")
    } else if has("avx2") {
        Some("AVX2")
    } else {
        None
    };
    Some(match simd {
        Some(s) => format!("{name} ({s})"),
        None => name,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_the_cpu_and_its_widest_vectors() {
        let info = "processor\t: 0\nmodel name\t: AMD EPYC\nflags\t\t: fpu sse2 avx fma avx2\n\nprocessor\t: 1\n";
        assert_eq!(cpu_name(info).as_deref(), Some("AMD EPYC (AVX2)"));
        let xeon = "model name : Intel Xeon\nflags : avx2 avx512f\n";
        assert_eq!(cpu_name(xeon).as_deref(), Some("Intel Xeon (AVX-512)"));
        assert_eq!(cpu_name("nothing here"), None);
        let d = describe(1);
        assert!(d.ends_with(", 1 thread") && d.contains(" core"), "{d}");
    }
}
