//! The kernels' sources are WGSL with two additions, expanded before compilation:
//!
//! - `{{NAME}}` placeholders for the shape constants (the hidden width in vec4s, tile sizes);
//! - blocks between `//#unroll VAR COUNT` and `//#end`, repeated COUNT times with `{VAR}`
//!   replaced by 0, 1, ... (COUNT is a number or a placeholder's value; blocks nest).
//!
//! Unrolling by hand keeps a row of activations or weights in named registers (`x0`, `x1`,
//! ...): a function-local array indexed in a loop is left in memory by some drivers, which
//! makes every access a load.

/// Expands `source` with `constants` (name, value).
pub(crate) fn expand(source: &str, constants: &[(&str, usize)]) -> String {
    let mut text = source.to_string();
    for (name, value) in constants {
        text = text.replace(&format!("{{{{{name}}}}}"), &value.to_string());
    }
    let lines: Vec<&str> = text.lines().collect();
    let mut out = String::with_capacity(text.len() * 2);
    let mut i = 0;
    unroll(&lines, &mut i, constants, &mut out, false);
    out
}

/// Copies lines from `*i` up to a closing `//#end` (when `inside`) or the end.
fn unroll(
    lines: &[&str],
    i: &mut usize,
    constants: &[(&str, usize)],
    out: &mut String,
    inside: bool,
) {
    while *i < lines.len() {
        let line = lines[*i];
        *i += 1;
        let directive = line.trim_start();
        if directive.starts_with("//#end") {
            assert!(inside, "unmatched //#end in a kernel source");
            return;
        }
        if let Some(rest) = directive.strip_prefix("//#unroll ") {
            let mut words = rest.split_whitespace();
            let (Some(var), Some(count)) = (words.next(), words.next()) else {
                panic!("//#unroll needs a variable and a count: {line}");
            };
            let count = count.parse::<usize>().unwrap_or_else(|_| {
                constants
                    .iter()
                    .find(|(name, _)| *name == count)
                    .map(|&(_, v)| v)
                    .unwrap_or_else(|| panic!("unknown unroll count {count}"))
            });
            // The body, expanded once (inner blocks included), then repeated.
            let mut body = String::new();
            unroll(lines, i, constants, &mut body, true);
            let pattern = format!("{{{var}}}");
            for k in 0..count {
                out.push_str(&body.replace(&pattern, &k.to_string()));
            }
            continue;
        }
        out.push_str(line);
        out.push('\n');
    }
    assert!(!inside, "//#unroll without //#end in a kernel source");
}

#[cfg(test)]
mod tests {
    use super::expand;

    #[test]
    fn blocks_repeat_and_nest() {
        let src = "a {{N}}\n//#unroll i N\nx{i}\n  //#unroll j 2\n  y{i}{j}\n  //#end\n//#end\nz\n";
        assert_eq!(
            expand(src, &[("N", 2)]),
            "a 2\nx0\n  y00\n  y01\nx1\n  y10\n  y11\nz\n"
        );
    }
}
