//! `{name}` placeholders in command templates (the sync port's frame
//! command, the external camera's arguments): one parser of literal text,
//! `{{` / `}}` escapes and named fields, each caller naming its own fields.

/// A run of literal text, or a field to substitute.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Part<F> {
    Lit(String),
    Field(F),
}

/// Splits `text` into literal runs and the fields of `fields` (name →
/// field); an unclosed placeholder, an unknown name or a lone `}` is an
/// error saying which (the known names listed).
pub fn parse<F: Copy>(text: &str, fields: &[(&str, F)]) -> Result<Vec<Part<F>>, String> {
    let mut parts = Vec::new();
    let mut lit = String::new();
    let mut chars = text.chars().peekable();
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
                let field = field(&mut chars, fields)?;
                if !lit.is_empty() {
                    parts.push(Part::Lit(std::mem::take(&mut lit)));
                }
                parts.push(Part::Field(field));
            }
            '}' => return Err("unmatched `}` (write `}}` for a literal brace)".into()),
            c => lit.push(c),
        }
    }
    if !lit.is_empty() {
        parts.push(Part::Lit(lit));
    }
    Ok(parts)
}

/// The field named by the characters up to the closing brace.
fn field<F: Copy>(
    chars: &mut impl Iterator<Item = char>,
    fields: &[(&str, F)],
) -> Result<F, String> {
    let mut name = String::new();
    loop {
        match chars.next() {
            Some('}') => break,
            Some(c) => name.push(c),
            None => return Err(format!("unclosed placeholder `{{{name}`")),
        }
    }
    match fields.iter().find(|(n, _)| *n == name) {
        Some(&(_, f)) => Ok(f),
        None => {
            let known: Vec<String> = fields.iter().map(|(n, _)| format!("{{{n}}}")).collect();
            Err(format!(
                "unknown placeholder `{{{name}}}` (known: {})",
                known.join(", ")
            ))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FIELDS: [(&str, char); 2] = [("a", 'A'), ("bc", 'B')];

    #[test]
    fn splits_literals_escapes_and_fields() {
        let parts = parse("x{a}{{y}}{bc}", &FIELDS).unwrap();
        assert_eq!(
            parts,
            [
                Part::Lit("x".into()),
                Part::Field('A'),
                Part::Lit("{y}".into()),
                Part::Field('B'),
            ]
        );
        assert_eq!(parse("", &FIELDS).unwrap(), []);
    }

    #[test]
    fn errors_say_which_brace_or_name() {
        assert_eq!(
            parse("x{a", &FIELDS).unwrap_err(),
            "unclosed placeholder `{a`"
        );
        assert_eq!(
            parse("{zz}", &FIELDS).unwrap_err(),
            "unknown placeholder `{zz}` (known: {a}, {bc})"
        );
        assert_eq!(
            parse("a}b", &FIELDS).unwrap_err(),
            "unmatched `}` (write `}}` for a literal brace)"
        );
    }
}
