//! The small YAML subset that camera-calibration files use, parsed by hand: block mappings by
//! indentation, flow sequences and mappings (`[1, 2]`, `{rows: 3}`) that may span lines, block
//! sequences of scalars, plain and quoted scalars, comments. Directives (OpenCV's non-standard
//! `%YAML:1.0`), document markers and tags (`!!opencv-matrix`) are accepted and ignored, which a
//! conforming YAML parser would not do for OpenCV's header.

use std::fmt;

/// A parsed value.
#[derive(Debug, Clone, PartialEq)]
pub enum Node {
    /// A mapping, keys in file order, each with its 1-based line.
    Map(Vec<(String, Node, usize)>),
    /// A sequence.
    Seq(Vec<Node>),
    /// A scalar, unquoted.
    Scalar(String),
}

/// A syntax error with its 1-based line.
#[derive(Debug, Clone, PartialEq)]
pub struct YamlError {
    /// Line of the error.
    pub line: usize,
    /// What is wrong.
    pub msg: String,
}

impl fmt::Display for YamlError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "line {}: {}", self.line, self.msg)
    }
}

impl std::error::Error for YamlError {}

impl Node {
    /// The value of `key` in a mapping, with its line.
    pub fn get(&self, key: &str) -> Option<(&Node, usize)> {
        match self {
            Node::Map(m) => m.iter().find(|(k, _, _)| k == key).map(|(_, v, l)| (v, *l)),
            _ => None,
        }
    }
}

struct Line {
    no: usize,
    indent: usize,
    text: String,
}

fn strip_comment(s: &str) -> &str {
    let mut quote = None;
    for (i, c) in s.char_indices() {
        match (quote, c) {
            (None, '"' | '\'') => quote = Some(c),
            (Some(q), c) if c == q => quote = None,
            (None, '#') if i == 0 || s[..i].ends_with([' ', '\t']) => return &s[..i],
            _ => {}
        }
    }
    s
}

/// Parses a document whose top level is a mapping.
pub fn parse(text: &str) -> Result<Node, YamlError> {
    let mut lines = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let t = strip_comment(raw).trim_end();
        let body = t.trim_start();
        if body.is_empty() || body.starts_with('%') || body == "---" || body == "..." {
            continue;
        }
        if t.starts_with('\t') {
            return Err(YamlError {
                line: i + 1,
                msg: "tabs are not allowed for indentation".into(),
            });
        }
        lines.push(Line {
            no: i + 1,
            indent: t.len() - body.len(),
            text: body.to_string(),
        });
    }
    let mut pos = 0;
    let node = block(&lines, &mut pos, 0)?;
    if let Some(l) = lines.get(pos) {
        return Err(YamlError {
            line: l.no,
            msg: "unexpected indentation".into(),
        });
    }
    Ok(node)
}

fn strip_tag(s: &str) -> &str {
    let s = s.trim();
    if s.starts_with('!') {
        s.split_once(char::is_whitespace)
            .map_or("", |(_, r)| r.trim())
    } else {
        s
    }
}

/// A block (mapping or sequence) whose lines are indented at least `min`.
fn block(lines: &[Line], pos: &mut usize, min: usize) -> Result<Node, YamlError> {
    let Some(first) = lines.get(*pos) else {
        return Ok(Node::Map(vec![]));
    };
    let indent = first.indent;
    if indent < min {
        return Ok(Node::Map(vec![]));
    }
    if first.text.starts_with("- ") || first.text == "-" {
        let mut items = Vec::new();
        while let Some(l) = lines.get(*pos) {
            if l.indent != indent || !(l.text.starts_with("- ") || l.text == "-") {
                break;
            }
            let rest = strip_tag(&l.text[1..]);
            *pos += 1;
            items.push(value(rest, l.no, lines, pos, indent + 1)?);
        }
        return Ok(Node::Seq(items));
    }
    let mut map = Vec::new();
    while let Some(l) = lines.get(*pos) {
        if l.indent < indent {
            break;
        }
        if l.indent > indent {
            return Err(YamlError {
                line: l.no,
                msg: "unexpected indentation".into(),
            });
        }
        let Some((k, rest)) = split_key(&l.text) else {
            return Err(YamlError {
                line: l.no,
                msg: format!("expected `key: value`, found {:?}", l.text),
            });
        };
        let no = l.no;
        *pos += 1;
        let v = value(strip_tag(rest), no, lines, pos, indent + 1)?;
        map.push((unquote(k), v, no));
    }
    Ok(Node::Map(map))
}

fn split_key(s: &str) -> Option<(&str, &str)> {
    let i = s
        .find(": ")
        .or_else(|| s.ends_with(':').then(|| s.len() - 1))?;
    Some((s[..i].trim(), &s[i + 1..]))
}

/// The value after `key:` (or `- `): inline scalar, flow collection (joining continuation lines),
/// or a nested block.
fn value(
    rest: &str,
    no: usize,
    lines: &[Line],
    pos: &mut usize,
    min: usize,
) -> Result<Node, YamlError> {
    if rest.is_empty() {
        return match lines.get(*pos) {
            Some(l) if l.indent >= min => block(lines, pos, min),
            _ => Ok(Node::Scalar(String::new())),
        };
    }
    if rest.starts_with('[') || rest.starts_with('{') {
        let mut text = rest.to_string();
        while depth(&text) > 0 {
            let Some(l) = lines.get(*pos) else {
                return Err(YamlError {
                    line: no,
                    msg: "unclosed `[` or `{`".into(),
                });
            };
            text.push(' ');
            text.push_str(&l.text);
            *pos += 1;
        }
        let mut chars = text.chars().peekable();
        let node = flow(&mut chars, no)?;
        if chars.any(|c| !c.is_whitespace()) {
            return Err(YamlError {
                line: no,
                msg: "text after a closed flow collection".into(),
            });
        }
        return Ok(node);
    }
    Ok(Node::Scalar(unquote(rest)))
}

fn depth(s: &str) -> i32 {
    s.chars().fold(0, |d, c| match c {
        '[' | '{' => d + 1,
        ']' | '}' => d - 1,
        _ => d,
    })
}

fn unquote(s: &str) -> String {
    let s = s.trim();
    for q in ['"', '\''] {
        if s.len() >= 2 && s.starts_with(q) && s.ends_with(q) {
            return s[1..s.len() - 1].to_string();
        }
    }
    s.to_string()
}

type Chars<'a> = std::iter::Peekable<std::str::Chars<'a>>;

fn flow(c: &mut Chars, no: usize) -> Result<Node, YamlError> {
    let err = |msg: &str| YamlError {
        line: no,
        msg: msg.into(),
    };
    while c.peek().is_some_and(|c| c.is_whitespace()) {
        c.next();
    }
    match c.peek() {
        Some('[') | Some('{') => {
            let open = c.next().unwrap_or('[');
            let close = if open == '[' { ']' } else { '}' };
            let mut seq = Vec::new();
            let mut map = Vec::new();
            loop {
                while c.peek().is_some_and(|c| c.is_whitespace() || *c == ',') {
                    c.next();
                }
                if c.peek() == Some(&close) {
                    c.next();
                    break;
                }
                if c.peek().is_none() {
                    return Err(err("unclosed flow collection"));
                }
                if open == '[' {
                    seq.push(flow(c, no)?);
                } else {
                    let key: String = scalar_text(c, true);
                    if c.next() != Some(':') {
                        return Err(err("expected `key: value` in a flow mapping"));
                    }
                    map.push((unquote(&key), flow(c, no)?, no));
                }
            }
            Ok(if open == '[' {
                Node::Seq(seq)
            } else {
                Node::Map(map)
            })
        }
        _ => Ok(Node::Scalar(unquote(&scalar_text(c, false)))),
    }
}

fn scalar_text(c: &mut Chars, key: bool) -> String {
    let mut s = String::new();
    while let Some(&ch) = c.peek() {
        if ch == ',' || ch == ']' || ch == '}' || (key && ch == ':') {
            break;
        }
        s.push(ch);
        c.next();
    }
    s.trim().to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn opencv_header_tags_and_multiline_flow() {
        let t = "%YAML:1.0\n---\nimage_width: 640\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 1., 0., 3.,\n       4., 5.e+02, 6. ]\nname: \"cam # 1\" # comment\n";
        let n = parse(t).unwrap();
        assert_eq!(n.get("image_width").unwrap().0, &Node::Scalar("640".into()));
        let (m, line) = n.get("camera_matrix").unwrap();
        assert_eq!(line, 4);
        match m.get("data").unwrap().0 {
            Node::Seq(v) => {
                assert_eq!(v.len(), 6);
                assert_eq!(v[4], Node::Scalar("5.e+02".into()));
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(n.get("name").unwrap().0, &Node::Scalar("cam # 1".into()));
    }

    #[test]
    fn flow_mapping_and_block_sequence() {
        let n = parse("k: {rows: 1, data: [1, 2]}\nl:\n  - 3\n  - 4\n").unwrap();
        assert_eq!(
            n.get("k").unwrap().0.get("data").unwrap().0,
            &Node::Seq(vec![Node::Scalar("1".into()), Node::Scalar("2".into())])
        );
        assert_eq!(
            n.get("l").unwrap().0,
            &Node::Seq(vec![Node::Scalar("3".into()), Node::Scalar("4".into())])
        );
    }

    #[test]
    fn errors_name_the_line() {
        let e = parse("a: 1\n   b: 2\n").unwrap_err();
        assert_eq!(e.line, 2, "{e}");
        let e = parse("a: [1, 2\n").unwrap_err();
        assert_eq!(e.line, 1, "{e}");
        let e = parse("a: 1\njust text\n").unwrap_err();
        assert!(e.to_string().contains("line 2"), "{e}");
    }
}
