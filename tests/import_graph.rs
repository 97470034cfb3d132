//! The module-level import graph flows forward only (docs/pipeline.md, "How the direction is
//! checked"). The compiler keeps the crates of `crates/` from naming each other in a circle; this
//! checks the order of the pipeline's modules inside and across them, reading the sources as
//! text, no compiler involved:
//!
//! 1. **Stages.** `src/lib.rs` states the order of the top-level modules in one doc line
//!    (`a` / `b` → `c` → …; modules joined by `/` share a rank). A module may name (`crate::x…`,
//!    `cac_y::x…`) only modules of an earlier rank. A crate is one module (`cac-scene` is
//!    `scene`) or several (`cac-eval` is `eval`, with `study` beside it; see
//!    [`CRATES`]). The exceptions are listed below, each with its reason.
//! 2. **No circle among siblings.** In every folder of `src/` (the library and the `cac` binary's
//!    `cli/` alike) the files that name each other directly (`super::x`, `crate::…::x`) form no
//!    circle.
//!
//! Paths are read from `use` items (groups expanded) and from paths in code; comments, string
//! literals and inline `mod tests { … }` are skipped. A name re-exported by a parent (`super::X`
//! with `X` defined elsewhere) counts as an edge to the parent, i.e. none.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Imports against the stage order that are known and allowed, each with its reason:
/// (from module, to module, file, reason).
const EXCEPTIONS: &[(&str, &str, &str, &str)] = &[];

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The path roots that name the project's own modules.
const ROOTS: [&str; 13] = [
    "crate",
    "super",
    "self",
    "cac_core",
    "cac_scene",
    "cac_render",
    "cac_detect",
    "cac_export",
    "cac_attack",
    "cac_eval",
    "cac_physical",
    "cac_video",
    "cac_bench",
];

/// The crates under `crates/`: folder, the module its `lib.rs` is (none: only the listed
/// modules), and the pipeline modules declared beside it.
const CRATES: &[(&str, Option<&str>, &[&str])] = &[
    (
        "core",
        None,
        &["choice", "colour", "io", "memory", "printer", "report"],
    ),
    ("scene", Some("scene"), &[]),
    ("render", Some("render"), &["config", "environment"]),
    ("detect", Some("detect"), &[]),
    ("export", Some("export"), &[]),
    ("attack", Some("attack"), &[]),
    ("eval", Some("eval"), &["study"]),
    ("physical", Some("physical"), &["sim"]),
    ("video", Some("video"), &[]),
    ("bench", Some("bench"), &[]),
];

/// The module path where crate `krate`'s `crate::first…` lies in the pipeline's module tree.
fn crate_base(krate: &str, first: Option<&str>) -> Vec<String> {
    let (_, main, extra) = CRATES
        .iter()
        .find(|c| c.0 == krate)
        .unwrap_or_else(|| panic!("crates/{krate} is not listed in CRATES"));
    match main {
        Some(m) if !first.is_some_and(|f| extra.contains(&f)) => vec![m.to_string()],
        _ => vec![],
    }
}

/// The source without comments and string/char literals (replaced by spaces, lines kept).
fn strip(src: &str) -> String {
    let b: Vec<char> = src.chars().collect();
    let mut out = String::with_capacity(src.len());
    let mut i = 0;
    while i < b.len() {
        let c = b[i];
        let next = b.get(i + 1).copied();
        if c == '/' && next == Some('/') {
            while i < b.len() && b[i] != '\n' {
                i += 1;
            }
        } else if c == '/' && next == Some('*') {
            i += 2;
            while i < b.len() && !(b[i] == '*' && b.get(i + 1) == Some(&'/')) {
                if b[i] == '\n' {
                    out.push('\n');
                }
                i += 1;
            }
            i += 2;
        } else if c == 'r' && (next == Some('"') || next == Some('#')) && !ident_char(&b, i) {
            // Raw string r"…" or r#"…"#.
            let mut j = i + 1;
            let mut hashes = 0;
            while j < b.len() && b[j] == '#' {
                hashes += 1;
                j += 1;
            }
            if b.get(j) != Some(&'"') {
                out.push(c);
                i += 1;
                continue;
            }
            j += 1;
            loop {
                if j >= b.len() {
                    break;
                }
                if b[j] == '"' && (0..hashes).all(|k| b.get(j + 1 + k) == Some(&'#')) {
                    j += 1 + hashes;
                    break;
                }
                if b[j] == '\n' {
                    out.push('\n');
                }
                j += 1;
            }
            out.push(' ');
            i = j;
        } else if c == '"' {
            i += 1;
            while i < b.len() && b[i] != '"' {
                if b[i] == '\\' {
                    i += 1;
                }
                if b.get(i) == Some(&'\n') {
                    out.push('\n');
                }
                i += 1;
            }
            i += 1;
            out.push(' ');
        } else if c == '\'' {
            // A char literal ('x', '\n', '\u{..}'), not a lifetime ('a).
            let close = if next == Some('\\') {
                (i + 2..b.len().min(i + 12)).find(|&k| b[k] == '\'')
            } else if b.get(i + 2) == Some(&'\'') {
                Some(i + 2)
            } else {
                None
            };
            match close {
                Some(k) => {
                    out.push(' ');
                    i = k + 1;
                }
                None => {
                    out.push(c);
                    i += 1;
                }
            }
        } else {
            out.push(c);
            i += 1;
        }
    }
    out
}

fn ident_char(b: &[char], i: usize) -> bool {
    i > 0 && (b[i - 1].is_alphanumeric() || b[i - 1] == '_')
}

/// Cuts the source at the first inline module (`mod tests {`): paths inside it are relative to
/// the file itself.
fn without_inline_modules(src: &str) -> String {
    let mut out = String::new();
    for line in src.lines() {
        let t = line.trim();
        let t = t.strip_prefix("pub ").unwrap_or(t);
        if t.starts_with("mod ") && t.ends_with('{') {
            break;
        }
        out.push_str(line);
        out.push('\n');
    }
    out
}

/// Expands a use tree (`a::{b, c::{d, e}}`) into its paths.
fn expand(tree: &str) -> Vec<String> {
    // `x as y` keeps `x`; then white space goes.
    let words: Vec<&str> = tree.split_whitespace().collect();
    let tree: String = words.join(" ").replace(" as ", "@").replace(' ', "");
    let Some(open) = tree.find('{') else {
        return vec![tree.split('@').next().unwrap_or(&tree).to_string()];
    };
    let prefix = &tree[..open];
    let inner = &tree[open + 1..tree.rfind('}').unwrap_or(tree.len())];
    let mut parts = Vec::new();
    let (mut depth, mut start) = (0, 0);
    for (k, ch) in inner.char_indices() {
        match ch {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                parts.push(&inner[start..k]);
                start = k + 1;
            }
            _ => {}
        }
    }
    parts.push(&inner[start..]);
    parts
        .into_iter()
        .filter(|p| !p.is_empty())
        .flat_map(|p| {
            expand(p).into_iter().map(move |q| {
                if q == "self" {
                    prefix.trim_end_matches("::").to_string()
                } else {
                    format!("{prefix}{q}")
                }
            })
        })
        .collect()
}

/// Every path named in `code` that starts with one of `roots` (`crate`, `super`, `self`, `cac`).
fn paths(code: &str, roots: &[&str]) -> Vec<String> {
    let mut out = Vec::new();
    // `use` items, groups expanded.
    let mut rest = code;
    while let Some(k) = find_word(rest, "use") {
        let after = &rest[k + 3..];
        let end = after.find(';').unwrap_or(after.len());
        out.extend(expand(after[..end].trim()));
        rest = &after[end..];
    }
    // Paths in code.
    let b: Vec<char> = code.chars().collect();
    let mut i = 0;
    while i < b.len() {
        if (b[i].is_alphabetic() || b[i] == '_') && !ident_char(&b, i) {
            let mut j = i;
            while j < b.len() && (b[j].is_alphanumeric() || b[j] == '_' || b[j] == ':') {
                j += 1;
            }
            let p: String = b[i..j].iter().collect();
            if p.contains("::") && !p.ends_with("::") {
                out.push(p);
            }
            i = j.max(i + 1);
        } else {
            i += 1;
        }
    }
    out.into_iter()
        .filter(|p| roots.iter().any(|r| p.split("::").next() == Some(*r)))
        .collect()
}

fn find_word(s: &str, w: &str) -> Option<usize> {
    let b = s.as_bytes();
    let mut from = 0;
    while let Some(k) = s[from..].find(w) {
        let k = from + k;
        let before = k == 0 || !(b[k - 1].is_ascii_alphanumeric() || b[k - 1] == b'_');
        let after = b.get(k + w.len()).is_some_and(|c| c.is_ascii_whitespace());
        if before && after {
            return Some(k);
        }
        from = k + w.len();
    }
    None
}

/// A source file: which crate, its module path, and the text to read.
struct Source {
    file: String,
    /// `true` for the library crates, `false` for the `cac` binary.
    lib: bool,
    /// The crate's folder under `crates/` (empty for the `cac` package).
    krate: String,
    module: Vec<String>,
    code: String,
}

fn sources() -> Vec<Source> {
    let mut out = Vec::new();
    // The `cac` package: the binary's `cli/` (its `lib.rs` only re-exports the crates).
    let mut files = Vec::new();
    walk(&root().join("src"), &mut files);
    files.sort();
    for p in files {
        let rel = p.strip_prefix(root()).unwrap().to_path_buf();
        let mut module = module_of(p.strip_prefix(root().join("src")).unwrap());
        if module == ["lib"] || module == ["main"] {
            continue;
        }
        if module.last().is_some_and(|m| m == "mod") {
            module.pop();
        }
        out.push(source(&p, rel, false, "", module));
    }
    for (krate, _, _) in CRATES {
        let src = root().join("crates").join(krate).join("src");
        let mut files = Vec::new();
        walk(&src, &mut files);
        files.sort();
        for p in files {
            let mut module = module_of(p.strip_prefix(&src).unwrap());
            if module.last().is_some_and(|m| m == "mod") {
                module.pop();
            }
            if module == ["lib"] {
                module.clear();
            }
            let mut full = crate_base(krate, module.first().map(String::as_str));
            full.extend(module);
            if full.is_empty() {
                continue; // a lib.rs that only declares its modules
            }
            let rel = p.strip_prefix(root()).unwrap().to_path_buf();
            out.push(source(&p, rel, true, krate, full));
        }
    }
    out
}

fn module_of(rel: &Path) -> Vec<String> {
    rel.with_extension("")
        .components()
        .map(|c| c.as_os_str().to_string_lossy().to_string())
        .collect()
}

fn source(p: &Path, rel: PathBuf, lib: bool, krate: &str, module: Vec<String>) -> Source {
    let text = std::fs::read_to_string(p).unwrap();
    Source {
        file: rel.display().to_string(),
        lib,
        krate: krate.to_string(),
        module,
        code: without_inline_modules(&strip(&text)),
    }
}

fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            walk(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The module path (in the pipeline's module tree) that a path names, or `None` for a crate
/// outside the project.
fn resolve(src: &Source, path: &str) -> Option<Vec<String>> {
    let segs: Vec<&str> = path.split("::").collect();
    let mut base: Vec<String> = match segs[0] {
        "crate" if src.lib => crate_base(&src.krate, segs.get(1).copied()),
        "crate" => vec![],
        "self" => src.module.clone(),
        "super" => src.module.clone(),
        c => match c.strip_prefix("cac_") {
            Some(k) if CRATES.iter().any(|x| x.0 == k) => crate_base(k, segs.get(1).copied()),
            _ => return None,
        },
    };
    let mut k = 0;
    while segs.get(k) == Some(&"super") {
        base.pop();
        k += 1;
    }
    if segs[0] != "super" {
        k = 1;
    }
    base.extend(
        segs[k..]
            .iter()
            .filter(|s| **s != "self" && **s != "*")
            .map(|s| s.to_string()),
    );
    Some(base)
}

/// The stage order stated in `src/lib.rs`: the rank of each top-level module.
fn stage_order() -> BTreeMap<String, usize> {
    let lib = std::fs::read_to_string(root().join("src/lib.rs")).unwrap();
    let line = lib
        .lines()
        .find(|l| l.starts_with("//!") && l.contains('→'))
        .expect("src/lib.rs states the stage order in a `//!` line with →");
    let mut rank = BTreeMap::new();
    for (r, group) in line.trim_start_matches("//!").split('→').enumerate() {
        for m in group.split('/') {
            let m = m.trim().trim_end_matches('.').trim().trim_matches('`');
            assert!(!m.is_empty(), "empty module in the stage order: {line}");
            assert!(
                rank.insert(m.to_string(), r).is_none(),
                "{m} appears twice in the stage order"
            );
        }
    }
    // Every module the library re-exports has a place.
    for (_, main, extra) in CRATES {
        for m in main.iter().chain(extra.iter()) {
            assert!(
                rank.contains_key(*m),
                "`{m}` has no place in the stage order of src/lib.rs: {line}"
            );
        }
    }
    rank
}

#[test]
fn no_module_imports_from_a_later_stage() {
    let rank = stage_order();
    let mut bad = BTreeSet::new();
    let mut used_exceptions = BTreeSet::new();
    let srcs = sources();
    for (k, _, _) in CRATES {
        assert!(
            srcs.iter().filter(|s| s.krate == *k).count() > 1,
            "no sources read in crates/{k}"
        );
    }
    for s in srcs.iter().filter(|s| s.lib) {
        let from = &s.module[0];
        for p in paths(&s.code, &ROOTS) {
            let Some(to) = resolve(s, &p) else { continue };
            let Some(to) = to.first() else { continue };
            if to == from || !rank.contains_key(to) {
                continue;
            }
            if rank[to] < rank[from] {
                continue;
            }
            if let Some(e) = EXCEPTIONS
                .iter()
                .find(|e| e.0 == from && e.1 == to && e.2 == s.file)
            {
                used_exceptions.insert(e.2);
                continue;
            }
            bad.insert(format!("{}: {from} → {to} ({p})", s.file));
        }
    }
    assert!(
        bad.is_empty(),
        "imports from a later (or the same) stage, against the order in src/lib.rs:\n{}",
        bad.into_iter().collect::<Vec<_>>().join("\n")
    );
    for e in EXCEPTIONS {
        assert!(
            used_exceptions.contains(e.2),
            "the exception {} → {} in {} is no longer needed: remove it from EXCEPTIONS",
            e.0,
            e.1,
            e.2
        );
    }
}

#[test]
fn sibling_modules_form_no_circle() {
    // Edges between the children of one parent module, per crate.
    let srcs = sources();
    let known: BTreeSet<(bool, Vec<String>)> =
        srcs.iter().map(|s| (s.lib, s.module.clone())).collect();
    #[allow(clippy::type_complexity)]
    let mut edges: BTreeMap<(bool, Vec<String>), BTreeSet<(String, String)>> = BTreeMap::new();
    for s in &srcs {
        for p in paths(&s.code, &ROOTS) {
            let Some(to) = resolve(s, &p) else { continue };
            let common = s.module.iter().zip(&to).take_while(|(a, b)| a == b).count();
            if common >= s.module.len() || common >= to.len() {
                continue; // ancestor or descendant: a parent and its children
            }
            if s.lib
                && common == 0
                && EXCEPTIONS
                    .iter()
                    .any(|e| e.2 == s.file && e.0 == s.module[0] && e.1 == to[0])
            {
                continue; // a listed exception (see EXCEPTIONS)
            }
            let parent = s.module[..common].to_vec();
            let mut child = parent.clone();
            child.push(to[common].clone());
            if !known.contains(&(s.lib, child)) {
                continue; // an item of the parent (a re-export), not a sibling module
            }
            edges
                .entry((s.lib, parent))
                .or_default()
                .insert((s.module[common].clone(), to[common].clone()));
        }
    }
    let mut circles = Vec::new();
    for ((lib, parent), es) in &edges {
        let nodes: BTreeSet<&String> = es.iter().flat_map(|(a, b)| [a, b]).collect();
        for start in &nodes {
            // Is `start` reachable from itself?
            let mut seen = BTreeSet::new();
            let mut stack: Vec<&String> = vec![start];
            let mut path_back: BTreeMap<&String, &String> = BTreeMap::new();
            let mut found = None;
            while let Some(n) = stack.pop() {
                for (a, b) in es.iter().filter(|(a, _)| a == n) {
                    if b == *start {
                        found = Some(a);
                        break;
                    }
                    if seen.insert(b) {
                        path_back.insert(b, a);
                        stack.push(b);
                    }
                }
                if found.is_some() {
                    break;
                }
            }
            if let Some(mut last) = found {
                let mut cycle = vec![last.clone()];
                while last != *start {
                    last = path_back[last];
                    cycle.push(last.clone());
                }
                cycle.reverse();
                cycle.push((*start).clone());
                let krate = if *lib { "cac" } else { "cac (binary)" };
                let at = if parent.is_empty() {
                    krate.to_string()
                } else {
                    format!("{krate}::{}", parent.join("::"))
                };
                circles.push(format!("{at}: {}", cycle.join(" → ")));
            }
        }
    }
    circles.sort();
    circles.dedup();
    assert!(
        circles.is_empty(),
        "sibling modules that import each other in a circle:\n{}",
        circles.join("\n")
    );
}

#[test]
fn the_reader_sees_groups_and_skips_comments_and_strings() {
    let code = strip(
        "use crate::{a::{b, c}, d};\n// use crate::x;\nlet s = \"crate::y::z\";\nlet c = '\"';\ncrate::e::f(1);\n",
    );
    let mut p = paths(&code, &["crate"]);
    p.sort();
    assert_eq!(p, ["crate::a::b", "crate::a::c", "crate::d", "crate::e::f"]);
}
