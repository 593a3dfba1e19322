//! The kernels' WGSL as the crate embeds it: each `src/shaders/*.wgsl` with its comments
//! blanked. The comments are for readers of the repository; in the web site's download they
//! were half of the kernels' bytes. The `//#` template directives stay (`template.rs`), and
//! so does every line, so that a shader compiler's line numbers still point into the source.

use std::path::Path;

fn main() -> std::io::Result<()> {
    let out_dir = std::env::var_os("OUT_DIR").ok_or_else(|| std::io::Error::other("no OUT_DIR"))?;
    let out = Path::new(&out_dir).join("shaders");
    std::fs::create_dir_all(&out)?;
    println!("cargo::rerun-if-changed=src/shaders");
    for entry in std::fs::read_dir("src/shaders")? {
        let path = entry?.path();
        if path.extension().is_some_and(|e| e == "wgsl") {
            let source = std::fs::read_to_string(&path)?;
            if let Some(name) = path.file_name() {
                std::fs::write(out.join(name), without_comments(&source))?;
            }
        }
    }
    Ok(())
}

/// `source` with each `//` comment removed (a `//#` directive kept), line for line.
fn without_comments(source: &str) -> String {
    let mut out = String::with_capacity(source.len());
    for line in source.lines() {
        let code = match line.find("//") {
            Some(at) if !line[at..].starts_with("//#") => line[..at].trim_end(),
            _ => line,
        };
        out.push_str(code);
        out.push('\n');
    }
    out
}
