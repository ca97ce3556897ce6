//! No import loop anywhere in `src/` (issue #15): among the modules of one parent, imports run
//! one way. A module may use its parent's items (that is where shared types live) and its
//! children's; between any other two modules the "uses" graph has no cycle.
//!
//! The graph is read from the source text: every path starting with `crate::` or `super::`,
//! in `use` items (brace groups expanded) and inline, outside comments and `mod tests`.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Module path (`volume::stream`) of every `.rs` file under `src/`, with its text.
fn modules(root: &Path) -> BTreeMap<Vec<String>, String> {
    let mut out = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).expect("src/ is readable").flatten() {
            let path = entry.path();
            if path.is_dir() {
                stack.push(path);
                continue;
            }
            if path.extension().and_then(|e| e.to_str()) != Some("rs") {
                continue;
            }
            let rel = path
                .strip_prefix(root)
                .expect("under src/")
                .with_extension("");
            let mut segs: Vec<String> = rel
                .components()
                .map(|c| c.as_os_str().to_string_lossy().into_owned())
                .collect();
            if matches!(
                segs.last().map(String::as_str),
                Some("mod" | "lib" | "main")
            ) {
                segs.pop();
            }
            let text = std::fs::read_to_string(&path).expect("source is UTF-8");
            out.insert(segs, text);
        }
    }
    out
}

/// The text without `//` comments and without the `mod tests` that ends a file.
fn code_of(text: &str) -> String {
    let text = text.split("#[cfg(test)]\nmod tests").next().unwrap_or("");
    text.lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

/// Every `crate::`/`super::` path in `code`, brace groups of `use` items expanded.
fn paths(code: &str) -> Vec<String> {
    let mut out = Vec::new();
    let bytes = code.as_bytes();
    let mut i = 0;
    while i < code.len() {
        let rest = &code[i..];
        let starts = rest.starts_with("crate::") || rest.starts_with("super::");
        let boundary = i == 0 || !(bytes[i - 1].is_ascii_alphanumeric() || bytes[i - 1] == b'_');
        if starts && boundary {
            let end = path_end(rest);
            expand(&rest[..end], &mut out);
            i += end.max(1);
        } else {
            i += rest.chars().next().map_or(1, char::len_utf8);
        }
    }
    out
}

/// Length of the path at the start of `s`: identifiers, `::` and balanced braces.
fn path_end(s: &str) -> usize {
    let mut depth = 0usize;
    for (i, c) in s.char_indices() {
        match c {
            '{' => depth += 1,
            '}' if depth > 0 => depth -= 1,
            c if depth > 0 && (c.is_whitespace() || c == ',') => {}
            c if c.is_alphanumeric() || c == '_' || c == ':' || c == '*' => {}
            _ if depth > 0 => {}
            _ => return i,
        }
        if depth == 0 && c == '}' {
            return i + 1;
        }
    }
    s.len()
}

/// `a::{b, c::{d}}` into `a::b`, `a::c::d`.
fn expand(path: &str, out: &mut Vec<String>) {
    let Some(open) = path.find('{') else {
        out.push(path.trim().trim_end_matches("::").to_string());
        return;
    };
    let prefix = &path[..open];
    let inner = &path[open + 1..path.rfind('}').unwrap_or(path.len())];
    let mut depth = 0usize;
    let mut start = 0;
    for (i, c) in inner.char_indices().chain([(inner.len(), ',')]) {
        match c {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                let part = inner[start..i].trim();
                if !part.is_empty() {
                    let part = if part == "self" { "" } else { part };
                    expand(&format!("{prefix}{part}"), out);
                }
                start = i + 1;
            }
            _ => {}
        }
    }
}

/// The module `path` (as written in module `from`) names, if one of `modules`.
fn target(
    from: &[String],
    path: &str,
    modules: &BTreeMap<Vec<String>, String>,
) -> Option<Vec<String>> {
    let mut segs: Vec<&str> = path.split("::").filter(|s| !s.is_empty()).collect();
    let mut base: Vec<String> = if segs.first() == Some(&"crate") {
        segs.remove(0);
        Vec::new()
    } else {
        from.to_vec()
    };
    while segs.first() == Some(&"super") {
        segs.remove(0);
        base.pop();
    }
    let full: Vec<String> = base
        .into_iter()
        .chain(segs.iter().map(|s| s.to_string()))
        .collect();
    (1..=full.len())
        .rev()
        .map(|k| full[..k].to_vec())
        .find(|m| modules.contains_key(m))
}

/// A cycle in `edges`, if any (depth-first search with colours).
fn cycle(edges: &BTreeMap<Vec<String>, BTreeSet<Vec<String>>>) -> Option<Vec<Vec<String>>> {
    fn visit(
        v: &Vec<String>,
        edges: &BTreeMap<Vec<String>, BTreeSet<Vec<String>>>,
        state: &mut BTreeMap<Vec<String>, u8>,
        stack: &mut Vec<Vec<String>>,
    ) -> Option<Vec<Vec<String>>> {
        state.insert(v.clone(), 1);
        stack.push(v.clone());
        for w in edges.get(v).into_iter().flatten() {
            match state.get(w).copied().unwrap_or(0) {
                0 => {
                    if let Some(c) = visit(w, edges, state, stack) {
                        return Some(c);
                    }
                }
                1 => {
                    let at = stack.iter().position(|s| s == w).unwrap_or(0);
                    return Some(stack[at..].to_vec());
                }
                _ => {}
            }
        }
        stack.pop();
        state.insert(v.clone(), 2);
        None
    }
    let mut state = BTreeMap::new();
    for v in edges.keys() {
        if !state.contains_key(v) {
            if let Some(c) = visit(v, edges, &mut state, &mut Vec::new()) {
                return Some(c);
            }
        }
    }
    None
}

/// The "uses" edges between modules that are neither ancestor nor descendant of each other.
fn edges(modules: &BTreeMap<Vec<String>, String>) -> BTreeMap<Vec<String>, BTreeSet<Vec<String>>> {
    let mut edges: BTreeMap<Vec<String>, BTreeSet<Vec<String>>> = BTreeMap::new();
    for (from, code) in modules {
        for p in paths(&code_of(code)) {
            let Some(to) = target(from, &p, modules) else {
                continue;
            };
            if !to.starts_with(from) && !from.starts_with(&to) {
                edges.entry(from.clone()).or_default().insert(to);
            }
        }
    }
    edges
}

#[test]
fn no_import_loop_in_src() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let modules = modules(&root);
    assert!(modules.contains_key(&vec!["volume".to_string(), "stream".to_string()]));
    let edges = edges(&modules);
    let count: usize = edges.values().map(BTreeSet::len).sum();
    assert!(
        count > 100,
        "only {count} imports found: the parser is broken"
    );
    if let Some(c) = cycle(&edges) {
        let names: Vec<String> = c.iter().map(|m| m.join("::")).collect();
        panic!("import loop: {} -> {}", names.join(" -> "), names[0]);
    }
}

/// The reader finds a loop where there is one, brace groups included.
#[test]
fn a_loop_is_found() {
    let module = |name: &str, code: &str| (vec!["v".to_string(), name.to_string()], code.into());
    let modules: BTreeMap<Vec<String>, String> = [
        (vec!["v".to_string()], String::new()),
        module("a", "use super::{b::X, c};"),
        module("b", "fn f() { crate::v::c::g() }"),
        module("c", "use super::{self as p, a::{Y}};"),
    ]
    .into_iter()
    .collect();
    let c = cycle(&edges(&modules)).expect("a -> b -> c -> a");
    assert_eq!(c.len(), 3);
    let acyclic: BTreeMap<Vec<String>, String> = [
        (vec!["v".to_string()], String::new()),
        module("a", "use super::{b::X, c};"),
        module("b", "// use super::a;\nuse super::Shared;"),
        module("c", "#[cfg(test)]\nmod tests { use super::super::a; }"),
    ]
    .into_iter()
    .collect();
    assert_eq!(cycle(&edges(&acyclic)), None);
}
