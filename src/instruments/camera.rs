//! The real camera backends: `files` (the acquisition software writes one
//! image per pattern into a folder) and `command` (a capture command run
//! per pattern), and the command template they share.

/// One piece of a command-line argument.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Piece {
    Lit(String),
    ExposureUs,
    Path,
    Pattern,
}

/// A capture command template split into argv (no shell): whitespace
/// separates arguments; `{exposure_us}`, `{path}`, `{pattern}` are
/// substituted inside each argument, so a substituted path may contain
/// spaces; `{{`, `}}` are literal braces.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CommandLine {
    args: Vec<Vec<Piece>>,
}

/// Values substituted into a [`CommandLine`].
#[derive(Debug, Clone, Copy)]
pub struct CommandValues<'a> {
    /// Exposure, µs.
    pub exposure_us: u64,
    /// Output file.
    pub path: &'a std::path::Path,
    /// Pattern name.
    pub pattern: &'a str,
}

impl CommandLine {
    /// Parses a template; the error says which placeholder is wrong.
    pub fn parse(template: &str) -> std::result::Result<CommandLine, String> {
        let args = template
            .split_whitespace()
            .map(parse_arg)
            .collect::<std::result::Result<Vec<_>, _>>()?;
        if args.is_empty() {
            return Err("empty command".into());
        }
        if !matches!(args[0].as_slice(), [Piece::Lit(_)]) {
            return Err("the program name must be literal text".into());
        }
        Ok(CommandLine { args })
    }

    /// The argv with the values substituted.
    pub fn argv(&self, v: &CommandValues) -> Vec<std::ffi::OsString> {
        self.args
            .iter()
            .map(|pieces| {
                let mut a = std::ffi::OsString::new();
                for p in pieces {
                    match p {
                        Piece::Lit(s) => a.push(s),
                        Piece::ExposureUs => a.push(v.exposure_us.to_string()),
                        Piece::Path => a.push(v.path.as_os_str()),
                        Piece::Pattern => a.push(v.pattern),
                    }
                }
                a
            })
            .collect()
    }
}

fn parse_arg(arg: &str) -> std::result::Result<Vec<Piece>, String> {
    let mut pieces = Vec::new();
    let mut lit = String::new();
    let mut chars = arg.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '{' if chars.peek() == Some(&'{') => {
                chars.next();
                lit.push('{');
            }
            '}' if chars.peek() == Some(&'}') => {
                chars.next();
                lit.push('}');
            }
            '{' => {
                let mut name = String::new();
                let mut closed = false;
                for c in chars.by_ref() {
                    if c == '}' {
                        closed = true;
                        break;
                    }
                    name.push(c);
                }
                let piece = match (closed, name.as_str()) {
                    (true, "exposure_us") => Piece::ExposureUs,
                    (true, "path") => Piece::Path,
                    (true, "pattern") => Piece::Pattern,
                    (false, _) => return Err(format!("unclosed placeholder `{{{name}`")),
                    _ => {
                        return Err(format!(
                            "unknown placeholder `{{{name}}}` (known: {{exposure_us}}, {{path}}, {{pattern}})"
                        ))
                    }
                };
                if !lit.is_empty() {
                    pieces.push(Piece::Lit(std::mem::take(&mut lit)));
                }
                pieces.push(piece);
            }
            '}' => return Err("unmatched `}` (write `}}` for a literal brace)".into()),
            c => lit.push(c),
        }
    }
    if !lit.is_empty() {
        pieces.push(Piece::Lit(lit));
    }
    Ok(pieces)
}
