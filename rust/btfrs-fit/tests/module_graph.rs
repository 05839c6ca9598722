//! The modules of btfrs-fit form no cycle: each top-level module (`src/x.rs` with its folder
//! `src/x/`) depends on others only through `crate::` paths (`use crate::...`, grouped
//! `use crate::{a, b::c}`, paths written inline, `$crate::` in macros, the crate root's
//! re-exports and exported macros resolved to the module that defines them), and following those
//! dependencies never leads back. Test code (`tests.rs` files, `#[cfg(test)]` items) may use
//! anything and is left out.

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// Every `.rs` file under `dir`.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in fs::read_dir(dir).unwrap() {
        let p = entry.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// The source without comments and without `#[cfg(test)]` items (a module block, a `mod x;`
/// declaration or a function).
fn library_code(text: &str) -> String {
    let no_comments: String = text.lines().map(|l| l.split("//").next().unwrap_or("")).collect::<Vec<_>>().join("\n");
    let mut s = no_comments;
    while let Some(at) = s.find("#[cfg(test)]") {
        let rest = &s[at..];
        let semi = rest.find(';');
        let brace = rest.find('{');
        let end = match (semi, brace) {
            (Some(i), Some(j)) if i < j => at + i + 1,
            (_, Some(j)) => {
                let mut depth = 0;
                let mut end = s.len();
                for (k, c) in s[at + j..].char_indices() {
                    match c {
                        '{' => depth += 1,
                        '}' => {
                            depth -= 1;
                            if depth == 0 {
                                end = at + j + k + 1;
                                break;
                            }
                        }
                        _ => {}
                    }
                }
                end
            }
            (Some(i), None) => at + i + 1,
            (None, None) => s.len(),
        };
        s.replace_range(at..end, "");
    }
    s
}

/// The identifiers after `crate::` in `code`: the first segment of each path, and the first
/// segment of each item of a group `crate::{a, b::c, d::{e, f}}`.
fn crate_paths(code: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = code;
    while let Some(i) = rest.find("crate::") {
        let after = &rest[i + "crate::".len()..];
        if let Some(group) = after.strip_prefix('{') {
            // Top-level items of the group (nested groups belong to their first segment).
            let mut depth = 0;
            let mut item = String::new();
            for c in group.chars() {
                match c {
                    '{' => depth += 1,
                    '}' if depth == 0 => break,
                    '}' => depth -= 1,
                    ',' if depth == 0 => {
                        out.push(first_segment(&item));
                        item.clear();
                        continue;
                    }
                    _ => {}
                }
                if depth == 0 {
                    item.push(c);
                }
            }
            out.push(first_segment(&item));
        } else {
            out.push(first_segment(after));
        }
        rest = &rest[i + "crate::".len()..];
    }
    out.retain(|s| !s.is_empty());
    out
}

fn first_segment(s: &str) -> String {
    s.trim_start().chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect()
}

/// The top-level modules, and the names the crate root re-exports or exports as macros, mapped
/// to the module that defines them.
fn modules_and_roots() -> (BTreeSet<String>, BTreeMap<String, String>) {
    let lib = fs::read_to_string(src().join("lib.rs")).unwrap();
    let code = library_code(&lib);
    let mut modules = BTreeSet::new();
    let mut roots = BTreeMap::new();
    for line in code.lines() {
        let l = line.trim();
        if let Some(m) = l.strip_prefix("pub mod ").or_else(|| l.strip_prefix("mod ")) {
            modules.insert(m.trim_end_matches(';').trim().to_string());
        }
        if let Some(u) = l.strip_prefix("pub use ") {
            let module = first_segment(u);
            let names = u.split_once("::{").map_or_else(
                || vec![u.rsplit("::").next().unwrap_or("").trim_end_matches(';').to_string()],
                |(_, g)| g.trim_end_matches("};").split(',').map(|n| n.trim().to_string()).collect(),
            );
            for n in names {
                roots.insert(n, module.clone());
            }
        }
    }
    // `#[macro_export]` macros live at the crate root but belong to the file that defines them.
    let mut files = Vec::new();
    rust_files(&src(), &mut files);
    for f in &files {
        let code = library_code(&fs::read_to_string(f).unwrap());
        let Some(top) = top_module(f) else { continue };
        let mut exported = false;
        for line in code.lines() {
            let l = line.trim();
            if l.starts_with("#[macro_export]") {
                exported = true;
            } else if let Some(m) = l.strip_prefix("macro_rules! ") {
                if exported {
                    roots.insert(first_segment(m), top.clone());
                }
                exported = false;
            }
        }
    }
    (modules, roots)
}

/// The top-level module a file belongs to (`None`: the crate root).
fn top_module(file: &Path) -> Option<String> {
    let rel = file.strip_prefix(src()).unwrap();
    let first = rel.components().next()?.as_os_str().to_str()?.to_string();
    if first == "lib.rs" {
        return None;
    }
    Some(first.trim_end_matches(".rs").to_string())
}

/// Each top-level module's dependencies on the others.
fn graph() -> BTreeMap<String, BTreeSet<String>> {
    let (modules, roots) = modules_and_roots();
    let mut files = Vec::new();
    rust_files(&src(), &mut files);
    let mut g: BTreeMap<String, BTreeSet<String>> = modules.iter().map(|m| (m.clone(), BTreeSet::new())).collect();
    for f in files {
        let Some(top) = top_module(&f) else { continue };
        if f.file_name().is_some_and(|n| n == "tests.rs") || f.components().any(|c| c.as_os_str() == "tests") {
            continue;
        }
        let code = library_code(&fs::read_to_string(&f).unwrap());
        for name in crate_paths(&code) {
            let target = if modules.contains(&name) { Some(name) } else { roots.get(&name).cloned() };
            if let Some(t) = target {
                if t != top {
                    g.get_mut(&top).unwrap_or_else(|| panic!("{} is not declared in lib.rs", top)).insert(t);
                }
            }
        }
    }
    g
}

/// A cycle through `g`, if any (depth-first search with colours).
fn find_cycle(g: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        n: &str,
        g: &BTreeMap<String, BTreeSet<String>>,
        state: &mut BTreeMap<String, u8>,
        path: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        state.insert(n.to_string(), 1);
        path.push(n.to_string());
        for m in &g[n] {
            match state.get(m.as_str()).copied().unwrap_or(0) {
                1 => {
                    let at = path.iter().position(|p| p == m).unwrap();
                    let mut cycle = path[at..].to_vec();
                    cycle.push(m.clone());
                    return Some(cycle);
                }
                0 => {
                    if let Some(c) = visit(m, g, state, path) {
                        return Some(c);
                    }
                }
                _ => {}
            }
        }
        path.pop();
        state.insert(n.to_string(), 2);
        None
    }
    let mut state = BTreeMap::new();
    for n in g.keys() {
        if state.get(n.as_str()).copied().unwrap_or(0) == 0 {
            if let Some(c) = visit(n, g, &mut state, &mut Vec::new()) {
                return Some(c);
            }
        }
    }
    None
}

#[test]
fn the_modules_of_btfrs_fit_form_no_cycle() {
    let g = graph();
    // The graph is read, not empty: the contract's modules are where they are expected.
    assert!(g["registry"].contains("model") && g["model"].contains("gpu") && g["gpu"].contains("eval"), "{g:#?}");
    assert!(g["driver"].contains("registry") && g["driver"].contains("robust"), "{g:#?}");
    if let Some(c) = find_cycle(&g) {
        panic!("the modules of btfrs-fit import each other in a cycle: {}\n{g:#?}", c.join(" -> "));
    }
}

#[test]
fn the_reader_of_the_graph_finds_cycles_and_test_code_is_left_out() {
    // The pieces on made-up sources: grouped and inline paths, `$crate`, test items skipped.
    let code = library_code(
        "use crate::{a, b::c, d::{e, f}};\nfn x() { crate::g::h(); $crate::i::j }\n\
         #[cfg(test)]\nmod tests { use crate::k; }\n#[cfg(test)]\nmod more;\n// crate::l\n",
    );
    assert_eq!(crate_paths(&code), ["a", "b", "d", "g", "i"]);
    let edges = |v: &[(&str, &[&str])]| -> BTreeMap<String, BTreeSet<String>> {
        v.iter().map(|(k, d)| (k.to_string(), d.iter().map(|s| s.to_string()).collect())).collect()
    };
    assert_eq!(find_cycle(&edges(&[("a", &["b"]), ("b", &["c"]), ("c", &[])])), None);
    assert_eq!(
        find_cycle(&edges(&[("a", &["b"]), ("b", &["c"]), ("c", &["a"])])).unwrap(),
        ["a", "b", "c", "a"].map(String::from)
    );
}
