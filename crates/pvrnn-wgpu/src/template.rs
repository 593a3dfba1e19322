//! The kernels' sources are WGSL with three additions, expanded before compilation:
//!
//! - `{{NAME}}` placeholders for the shape constants (the hidden width in vec4s, tile sizes);
//! - blocks between `//#unroll VAR COUNT` and `//#end`, repeated COUNT times with `{VAR}`
//!   replaced by 0, 1, ... (COUNT is a number or a placeholder's value; blocks nest);
//! - blocks between `//#if NAME` and `//#end`, with an optional `//#else`, kept where the
//!   constant NAME is not zero (the `//#else` part where it is): code whose very types
//!   differ between variants (a binding read as vec4s or as scalars), which a `const`
//!   condition cannot switch.
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
    expand_block(&lines, &mut i, constants, &mut out, false);
    out
}

/// How a block of lines ended.
#[derive(Debug, PartialEq)]
enum Close {
    End,
    Else,
    Source,
}

/// The value of `word`: a number, or a constant's.
fn value(word: &str, constants: &[(&str, usize)]) -> usize {
    word.parse::<usize>().unwrap_or_else(|_| {
        constants
            .iter()
            .find(|(name, _)| *name == word)
            .map(|&(_, v)| v)
            .unwrap_or_else(|| panic!("unknown constant {word} in a kernel source"))
    })
}

/// Copies lines from `*i` up to a closing `//#end` or `//#else` (when `inside`) or the
/// end, expanding the blocks within; says which closed it.
fn expand_block(
    lines: &[&str],
    i: &mut usize,
    constants: &[(&str, usize)],
    out: &mut String,
    inside: bool,
) -> Close {
    while *i < lines.len() {
        let line = lines[*i];
        *i += 1;
        let directive = line.trim_start();
        if directive.starts_with("//#end") {
            assert!(inside, "unmatched //#end in a kernel source");
            return Close::End;
        }
        if directive.starts_with("//#else") {
            assert!(inside, "unmatched //#else in a kernel source");
            return Close::Else;
        }
        if let Some(name) = directive.strip_prefix("//#if ") {
            let on = value(name.trim(), constants) != 0;
            // Both parts are expanded (so both are checked); the one that applies is kept.
            let (mut then, mut otherwise) = (String::new(), String::new());
            if expand_block(lines, i, constants, &mut then, true) == Close::Else {
                let close = expand_block(lines, i, constants, &mut otherwise, true);
                assert_eq!(close, Close::End, "//#if without //#end: {line}");
            }
            out.push_str(if on { &then } else { &otherwise });
            continue;
        }
        if let Some(rest) = directive.strip_prefix("//#unroll ") {
            let mut words = rest.split_whitespace();
            let (Some(var), Some(count)) = (words.next(), words.next()) else {
                panic!("//#unroll needs a variable and a count: {line}");
            };
            let count = value(count, constants);
            // The body, expanded once (inner blocks included), then repeated.
            let mut body = String::new();
            let close = expand_block(lines, i, constants, &mut body, true);
            assert_eq!(close, Close::End, "//#unroll without //#end: {line}");
            let pattern = format!("{{{var}}}");
            for k in 0..count {
                out.push_str(&body.replace(&pattern, &k.to_string()));
            }
            continue;
        }
        out.push_str(line);
        out.push('\n');
    }
    assert!(!inside, "a block without //#end in a kernel source");
    Close::Source
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

    #[test]
    fn conditional_blocks_keep_the_part_that_applies() {
        let src = "//#if V\nv{i}\n//#else\ns\n//#end\n//#if W\nw\n//#end\nz\n";
        let wrapped = format!("//#unroll i 2\n{src}//#end\n");
        assert_eq!(expand(src, &[("V", 1), ("W", 0)]), "v{i}\nz\n");
        assert_eq!(expand(src, &[("V", 0), ("W", 3)]), "s\nw\nz\n");
        assert_eq!(expand(&wrapped, &[("V", 1), ("W", 0)]), "v0\nz\nv1\nz\n");
    }
}
