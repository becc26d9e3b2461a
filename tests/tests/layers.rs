//! The code's shape, checked: no import circle among the modules of any crate, and ogm-core's
//! layers import only those below them (types < config < wire < map < sampler < lidar <
//! session). Read from the sources: every `crate::…` and `super::…` path outside comments,
//! strings and `#[cfg(test)]` modules is an edge from the module whose file holds it to the
//! module it names. Submodules count as their parent at the depth given per crate (so
//! `sampler::gibbs::sweep` is `sampler::gibbs`).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Module path of a source file relative to its crate's `src/`.
fn module_of(src: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src).expect("file under src");
    let mut parts: Vec<String> = rel
        .iter()
        .map(|p| p.to_string_lossy().trim_end_matches(".rs").to_string())
        .collect();
    if matches!(
        parts.last().map(String::as_str),
        Some("mod" | "lib" | "main")
    ) {
        parts.pop();
    }
    parts
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("readable source dir") {
        let path = entry.expect("dir entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The code of a file without comments, string and char literals, and `#[cfg(test)]` items.
fn code_of(text: &str) -> String {
    let b = text.as_bytes();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    while i < b.len() {
        if b[i..].starts_with(b"//") {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if b[i..].starts_with(b"/*") {
            let mut depth = 0;
            while i < b.len() {
                if b[i..].starts_with(b"/*") {
                    depth += 1;
                    i += 2;
                } else if b[i..].starts_with(b"*/") {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
        } else if b[i] == b'"' {
            i += 1;
            while i < b.len() && b[i] != b'"' {
                i += if b[i] == b'\\' { 2 } else { 1 };
            }
            i += 1;
            out.push_str("\"\"");
        } else if b[i] == b'\'' && i + 2 < b.len() && (b[i + 2] == b'\'' || b[i + 1] == b'\\') {
            // A char literal ('x' or '\n'); lifetimes ('a) have no closing quote here.
            i += 1;
            while i < b.len() && b[i] != b'\'' {
                i += if b[i] == b'\\' { 2 } else { 1 };
            }
            i += 1;
        } else {
            out.push(b[i] as char);
            i += 1;
        }
    }
    strip_test_items(&out)
}

/// Removes each `#[cfg(test)]` item (a `mod … { … }` or `use …;`).
fn strip_test_items(code: &str) -> String {
    let mut out = String::new();
    let mut rest = code;
    while let Some(at) = rest.find("#[cfg(test)]") {
        out.push_str(&rest[..at]);
        let after = &rest[at..];
        let brace = after.find('{');
        let semi = after.find(';');
        rest = match (brace, semi) {
            (Some(b), Some(s)) if s < b => &after[s + 1..],
            (Some(b), _) => {
                let mut depth = 0;
                let mut end = after.len();
                for (k, c) in after[b..].char_indices() {
                    match c {
                        '{' => depth += 1,
                        '}' => {
                            depth -= 1;
                            if depth == 0 {
                                end = b + k + 1;
                                break;
                            }
                        }
                        _ => {}
                    }
                }
                &after[end..]
            }
            _ => "",
        };
    }
    out.push_str(rest);
    out
}

/// Every path a `crate::` or `super::` prefix at `at` in `code` names (use-tree groups expanded).
fn paths_at(code: &str, at: usize, base: &[String], out: &mut Vec<Vec<String>>) {
    fn tree(s: &[u8], mut i: usize, prefix: Vec<String>, out: &mut Vec<Vec<String>>) -> usize {
        let mut path = prefix;
        loop {
            while i < s.len() && s[i].is_ascii_whitespace() {
                i += 1;
            }
            if i < s.len() && s[i] == b'{' {
                i += 1;
                loop {
                    i = tree(s, i, path.clone(), out);
                    while i < s.len() && (s[i].is_ascii_whitespace() || s[i] == b',') {
                        i += 1;
                    }
                    if i >= s.len() || s[i] == b'}' {
                        return i + 1;
                    }
                }
            }
            let start = i;
            while i < s.len() && (s[i].is_ascii_alphanumeric() || s[i] == b'_') {
                i += 1;
            }
            if start == i {
                out.push(path);
                return i;
            }
            match &s[start..i] {
                b"super" => {
                    path.pop();
                }
                b"self" => {}
                seg => path.push(String::from_utf8_lossy(seg).into_owned()),
            }
            if s[i..].starts_with(b"::") {
                i += 2;
            } else {
                out.push(path);
                return i;
            }
        }
    }
    tree(code.as_bytes(), at, base.to_vec(), out);
}

/// The module graph of the crate at `src`, modules cut to `depth` path segments.
fn graph(src: &Path, depth: usize) -> BTreeMap<String, BTreeSet<String>> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let node = |m: &[String]| m[..m.len().min(depth)].join("::");
    let modules: BTreeSet<Vec<String>> = files.iter().map(|f| module_of(src, f)).collect();
    let mut edges: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for file in &files {
        let here = module_of(src, file);
        let from = node(&here);
        let code = code_of(&std::fs::read_to_string(file).expect("readable source"));
        let mut named = Vec::new();
        for (at, _) in code.match_indices("crate::") {
            let before = code[..at].chars().next_back();
            if before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == '$') {
                continue;
            }
            paths_at(&code, at + "crate::".len(), &[], &mut named);
        }
        // `super::` from a file names its parent module's items (a `mod.rs` is its module).
        let parent: Vec<String> = here[..here.len().saturating_sub(1)].to_vec();
        for (at, _) in code.match_indices("super::") {
            let before = code[..at].chars().next_back();
            if before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == ':') {
                continue;
            }
            paths_at(&code, at + "super::".len(), &parent, &mut named);
        }
        for path in named {
            // The longest prefix of the path that is a module of this crate.
            let target = (1..=path.len())
                .rev()
                .map(|n| path[..n].to_vec())
                .find(|p| modules.contains(p));
            if let Some(target) = target {
                let to = node(&target);
                if !to.is_empty() && to != from {
                    edges.entry(from.clone()).or_default().insert(to);
                }
            }
        }
    }
    edges
}

/// The circles of a graph (strongly connected components of more than one module).
fn circles(edges: &BTreeMap<String, BTreeSet<String>>) -> Vec<Vec<String>> {
    // Kosaraju: order by finish time, then walk the reversed graph.
    fn visit(
        v: &str,
        e: &BTreeMap<String, BTreeSet<String>>,
        seen: &mut BTreeSet<String>,
        order: &mut Vec<String>,
    ) {
        if !seen.insert(v.to_string()) {
            return;
        }
        for w in e.get(v).into_iter().flatten() {
            visit(w, e, seen, order);
        }
        order.push(v.to_string());
    }
    let mut nodes: BTreeSet<String> = edges.keys().cloned().collect();
    nodes.extend(edges.values().flatten().cloned());
    let mut reversed: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for (a, bs) in edges {
        for b in bs {
            reversed.entry(b.clone()).or_default().insert(a.clone());
        }
    }
    let (mut seen, mut order) = (BTreeSet::new(), Vec::new());
    for v in &nodes {
        visit(v, edges, &mut seen, &mut order);
    }
    let mut assigned = BTreeSet::new();
    let mut out = Vec::new();
    for v in order.iter().rev() {
        let mut comp = Vec::new();
        visit(v, &reversed, &mut assigned, &mut comp);
        if comp.len() > 1 {
            comp.sort();
            out.push(comp);
        }
    }
    out
}

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("workspace root")
        .to_path_buf()
}

/// The crates whose modules must form no circle, with the depth a module is cut to.
fn crates() -> Vec<(PathBuf, usize)> {
    let mut out = vec![
        (root().join("ogm-core/src"), 2),
        (root().join("firmware/src"), 1),
        (root().join("host-sim/src"), 1),
    ];
    // Crates nested under host-sim (the field tools), each with its own src/.
    if let Ok(dir) = std::fs::read_dir(root().join("host-sim")) {
        for e in dir.flatten() {
            let src = e.path().join("src");
            if e.path().join("Cargo.toml").exists() && src.is_dir() {
                out.push((src, 1));
            }
        }
    }
    out
}

#[test]
fn no_crate_has_an_import_circle() {
    let mut found = Vec::new();
    for (src, depth) in crates() {
        let g = graph(&src, depth);
        assert!(!g.is_empty(), "{}: no modules read", src.display());
        for circle in circles(&g) {
            found.push(format!("{}: {}", src.display(), circle.join(" <-> ")));
        }
    }
    assert!(found.is_empty(), "import circles: {found:#?}");
}

/// ogm-core's layers, bottom up; a module may import its own layer's modules and those below.
const LAYERS: &[&[&str]] = &[
    &["error", "types", "fmt"],
    &["config"],
    &["wire"],
    &["map"],
    &["sampler"],
    &["localize"],
    &["lidar"],
    &["session"],
    &["reference"],
];

fn layer_of(module: &str) -> usize {
    let top = module.split("::").next().unwrap_or_default();
    LAYERS
        .iter()
        .position(|l| l.contains(&top))
        .unwrap_or_else(|| panic!("ogm-core module {module} is in no layer: add it to LAYERS"))
}

#[test]
fn ogm_core_layers_import_only_downwards() {
    let g = graph(&root().join("ogm-core/src"), 2);
    let mut upward = Vec::new();
    for (from, tos) in &g {
        if from.is_empty() {
            continue; // lib.rs declares and re-exports every layer
        }
        for to in tos {
            if layer_of(to) > layer_of(from) {
                upward.push(format!("{from} -> {to}"));
            }
        }
    }
    assert!(upward.is_empty(), "imports up the layers: {upward:#?}");
    // The wire is the bottom of the protocol: nothing of the mapper or the sampler.
    for to in g.get("wire").into_iter().flatten() {
        assert!(
            !to.starts_with("map") && !to.starts_with("sampler"),
            "wire imports {to}"
        );
    }
}

#[test]
fn the_checker_sees_a_circle_and_an_upward_import() {
    // A crate made on the spot: a -> b -> a, and a group import naming c.
    let dir = std::env::temp_dir().join(format!("ogm-layers-{}", std::process::id()));
    let src = dir.join("src");
    std::fs::create_dir_all(src.join("b")).expect("temp dir");
    std::fs::write(
        src.join("lib.rs"),
        "mod a; mod b; mod c;\n// crate::c::x in a comment is no edge\n",
    )
    .expect("write");
    std::fs::write(
        src.join("a.rs"),
        "use crate::{b::inner::X, c};\nconst S: &str = \"crate::c\";\n#[cfg(test)]\nmod tests { use crate::c::Y; }\n",
    )
    .expect("write");
    std::fs::write(src.join("b/mod.rs"), "pub mod inner;\n").expect("write");
    std::fs::write(src.join("b/inner.rs"), "use super::super::a::Z;\n").expect("write");
    std::fs::write(src.join("c.rs"), "pub struct Y;\n").expect("write");
    let g = graph(&src, 1);
    assert_eq!(g["a"], BTreeSet::from(["b".to_string(), "c".to_string()]));
    assert_eq!(g["b"], BTreeSet::from(["a".to_string()]));
    assert_eq!(circles(&g), vec![vec!["a".to_string(), "b".to_string()]]);
    std::fs::remove_dir_all(&dir).ok();
}
