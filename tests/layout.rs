//! Issue 27: the modules follow the data one way. A module's `use` of another (`crate::a::b`,
//! `super::x`, read from the sources outside comments and `tests` modules) is an edge; no
//! chain of edges may lead back to where it started. A parent's own items (`super::Item` in
//! mod.rs) are no edge: a module and its parent share them by construction.

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::Path;

type Graph = BTreeMap<String, BTreeSet<String>>;

/// `src/a/b.rs` or `src/a/b/mod.rs` as `a::b`.
fn module_of(root: &Path, file: &Path) -> String {
    let rel = file.strip_prefix(root).unwrap().with_extension("");
    let mut parts: Vec<String> = rel
        .iter()
        .map(|p| p.to_string_lossy().into_owned())
        .collect();
    if parts.last().is_some_and(|p| p == "mod") {
        parts.pop();
    }
    parts.join("::")
}

fn is_module(root: &Path, module: &str) -> bool {
    let p = root.join(module.replace("::", "/"));
    p.with_extension("rs").is_file() || p.join("mod.rs").is_file()
}

/// The source without comments and the `tests` module.
fn code(text: &str) -> String {
    let text = match text.find("#[cfg(test)]\nmod tests") {
        Some(i) => &text[..i],
        None => text,
    };
    text.lines()
        .map(|l| match l.find("//") {
            Some(i) => &l[..i],
            None => l,
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// Each `prefix` followed by a path (`a::b::c`) in `text`: the path's words.
fn paths_after<'a>(text: &'a str, prefix: &str) -> Vec<Vec<&'a str>> {
    text.match_indices(prefix)
        .map(|(i, _)| {
            let rest = &text[i + prefix.len()..];
            let end = rest
                .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_' || c == ':'))
                .unwrap_or(rest.len());
            rest[..end].split("::").filter(|w| !w.is_empty()).collect()
        })
        .collect()
}

/// The longest module named by the first words of `words` under `base` ("" for the crate).
fn target(root: &Path, base: &str, words: &[&str]) -> Option<String> {
    (1..=words.len()).rev().find_map(|n| {
        let m = if base.is_empty() {
            words[..n].join("::")
        } else {
            format!("{base}::{}", words[..n].join("::"))
        };
        is_module(root, &m).then_some(m)
    })
}

fn graph(root: &Path) -> Graph {
    let mut files = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for e in fs::read_dir(dir).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "rs") {
                files.push(p);
            }
        }
    }
    let mut g = Graph::new();
    for f in files {
        let me = module_of(root, &f);
        if me == "main" || me == "lib" {
            continue;
        }
        let text = code(&fs::read_to_string(&f).unwrap());
        let parent = me.rsplit_once("::").map_or("", |(p, _)| p).to_string();
        // mod.rs's `super` is its own parent; a file's `super` is its folder's module.
        let is_mod_rs = f.ends_with("mod.rs");
        let sup = if is_mod_rs {
            parent.rsplit_once("::").map_or("", |(p, _)| p).to_string()
        } else {
            parent.clone()
        };
        let mut out = BTreeSet::new();
        for words in paths_after(&text, "crate::") {
            out.extend(target(root, "", &words));
        }
        for words in paths_after(&text, "super::") {
            out.extend(target(root, &sup, &words));
        }
        // Not an edge: the module itself, its ancestors (their items), its descendants.
        out.retain(|t| {
            t != &me && !me.starts_with(&format!("{t}::")) && !t.starts_with(&format!("{me}::"))
        });
        g.insert(me, out);
    }
    g
}

/// A cycle of `g`, if any, as the modules along it.
fn cycle(g: &Graph) -> Option<Vec<String>> {
    fn visit(
        g: &Graph,
        m: &str,
        path: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) -> Option<Vec<String>> {
        if let Some(i) = path.iter().position(|p| p == m) {
            let mut c = path[i..].to_vec();
            c.push(m.to_string());
            return Some(c);
        }
        if done.contains(m) {
            return None;
        }
        path.push(m.to_string());
        for next in g.get(m).into_iter().flatten() {
            if let Some(c) = visit(g, next, path, done) {
                return Some(c);
            }
        }
        path.pop();
        done.insert(m.to_string());
        None
    }
    let mut done = BTreeSet::new();
    g.keys()
        .find_map(|m| visit(g, m, &mut Vec::new(), &mut done))
}

#[test]
fn no_module_imports_its_way_back_to_itself() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let g = graph(&root);
    assert!(g.len() > 40, "only {} modules found", g.len());
    // The graph has the edges the layout is built on.
    assert!(g["pipeline"].contains("surface") && g["watch::runner"].contains("pipeline"));
    if let Some(c) = cycle(&g) {
        panic!("an import circle: {}", c.join(" -> "));
    }
    // Nor between the top-level modules (cluster reached up into watch for the clock).
    let mut top = Graph::new();
    for (m, out) in &g {
        let first = |x: &str| x.split("::").next().unwrap().to_string();
        let entry = top.entry(first(m)).or_default();
        entry.extend(out.iter().map(|t| first(t)).filter(|t| *t != first(m)));
    }
    if let Some(c) = cycle(&top) {
        panic!(
            "an import circle between top-level modules: {}",
            c.join(" -> ")
        );
    }
    // And the search finds a circle where there is one.
    let mut bad = g.clone();
    bad.get_mut("surface").unwrap().insert("pipeline".into());
    assert!(cycle(&bad).is_some());
}
