//! Structure check: the library's imports run one way (docs/ARCHITECTURE.md, "Layers").
//!
//! A plain text scan, no parser: every `.rs` file under `src/` belongs to the top-level module
//! named by its first path component (`src/control/nmpc.rs` → `control`, `src/config.rs` →
//! `config`; `lib.rs`, the crate root that re-exports the main types, is not scanned). Line
//! comments (`//`, `///`, `//!`) are removed first, so doc links to a higher layer are allowed;
//! then every `crate::name` and every `crate::{a::…, b, …}` group names the modules a file
//! uses. A module may use its own layer's lower layers only; `model` and `solver` share a
//! layer and use nothing of each other; below them, `check` (the range checks every settings
//! type's `validate()` shares) and `test_rng` (the unit tests' random numbers, `cfg(test)`)
//! use nothing of the crate.
//!
//! Inside a module, the files must not import each other in a circle
//! ([`no_import_circle_between_files`]): a file's `super::x` and `crate::module::x` paths are
//! edges to the sibling file `x.rs`, or, for a name the module root re-exports
//! (`pub use x::{Name, …}` in `mod.rs` or `module.rs`), to the file that defines it. The module
//! root itself (it declares and re-exports its files; items defined there are the module's face)
//! and each file's `#[cfg(test)] mod tests` are not part of this graph.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The layers, lowest first. A module may import modules of strictly lower layers only.
const LAYERS: &[&[&str]] = &[
    &["check", "test_rng", "math", "clock"],
    &["model", "solver"],
    &["estimate"],
    &["control"],
    &["sim"],
    &["runtime"],
    &["config"],
    &["scenario"],
];

/// Imports the layer order would allow but the design does not: the runtime's robot boundary
/// builds without the simulator (the virtual robot lives in `scenario`, where both meet).
const FORBIDDEN: &[(&str, &str)] = &[("runtime", "sim")];

fn layer_of(module: &str) -> Option<usize> {
    LAYERS.iter().position(|l| l.contains(&module))
}

/// Source text without line comments.
fn strip_comments(text: &str) -> String {
    text.lines()
        .map(|l| match l.find("//") {
            Some(i) => &l[..i],
            None => l,
        })
        .collect::<Vec<_>>()
        .join("\n")
}

fn ident_at(s: &str) -> &str {
    let end = s
        .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .unwrap_or(s.len());
    &s[..end]
}

/// The top-level names used through `crate::` in `text` (comments already removed).
fn crate_paths(text: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    for (i, _) in text.match_indices("crate::") {
        if i > 0 {
            let prev = text[..i].chars().next_back().unwrap_or(' ');
            if prev.is_ascii_alphanumeric() || prev == '_' {
                continue; // e.g. `exompc_crate::`
            }
        }
        let rest = &text[i + "crate::".len()..];
        if let Some(group) = rest.strip_prefix('{') {
            // `crate::{a::x, b}`: the first identifier of every top-level item.
            let mut depth = 0usize;
            let mut item_start = true;
            for (j, c) in group.char_indices() {
                match c {
                    '{' => depth += 1,
                    '}' if depth == 0 => break,
                    '}' => depth -= 1,
                    ',' if depth == 0 => item_start = true,
                    c if item_start && (c.is_ascii_alphabetic() || c == '_') => {
                        out.insert(ident_at(&group[j..]).to_string());
                        item_start = false;
                    }
                    _ => {}
                }
            }
        } else {
            let name = ident_at(rest);
            if !name.is_empty() {
                out.insert(name.to_string());
            }
        }
    }
    out
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// Every import of `(file, module, used module)` that goes upwards or sideways.
fn violations(files: &[(String, String)]) -> Vec<String> {
    let mut bad = Vec::new();
    for (rel, text) in files {
        let module = rel.split(['/', '.']).next().unwrap();
        if module == "lib" {
            continue;
        }
        let Some(own) = layer_of(module) else {
            bad.push(format!(
                "{rel}: module `{module}` has no layer in tests/layering.rs"
            ));
            continue;
        };
        for used in crate_paths(&strip_comments(text)) {
            if used == module {
                continue;
            }
            if FORBIDDEN.contains(&(module, used.as_str())) {
                bad.push(format!("{rel}: `{module}` must not import `crate::{used}`"));
                continue;
            }
            match layer_of(&used) {
                Some(l) if l < own => {}
                Some(_) => bad.push(format!(
                    "{rel}: `{module}` (layer {own}) imports `crate::{used}` (layer {})",
                    layer_of(&used).unwrap()
                )),
                None => {} // a root re-export or macro, not a module
            }
        }
    }
    bad
}

#[test]
fn library_imports_run_one_way() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut paths = Vec::new();
    rust_files(&src, &mut paths);
    let files: Vec<(String, String)> = paths
        .iter()
        .map(|p| {
            let rel = p
                .strip_prefix(&src)
                .unwrap()
                .to_string_lossy()
                .replace('\\', "/");
            (rel, std::fs::read_to_string(p).unwrap())
        })
        .collect();
    assert!(files.len() > 30, "found only {} files", files.len());
    let bad = violations(&files);
    assert!(
        bad.is_empty(),
        "imports against the layer order:\n{}",
        bad.join("\n")
    );
}

#[test]
fn every_library_module_has_a_layer() {
    let lib =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("src/lib.rs")).unwrap();
    for line in lib.lines() {
        if let Some(m) = line.trim().strip_prefix("pub mod ") {
            let m = m.trim_end_matches(';');
            assert!(layer_of(m).is_some(), "module `{m}` has no layer");
        }
    }
}

#[test]
fn the_scan_finds_upward_and_grouped_imports() {
    let f = |rel: &str, text: &str| vec![(rel.to_string(), text.to_string())];
    // Upward, grouped, and inline paths are found; comments and lower layers are not.
    assert_eq!(
        violations(&f("control/x.rs", "use crate::sim::Dof;")).len(),
        1
    );
    assert_eq!(
        violations(&f(
            "control/x.rs",
            "use crate::{model::Real, config::Scenario};"
        ))
        .len(),
        1
    );
    assert_eq!(
        violations(&f("sim/x.rs", "fn f(s: &crate::scenario::RunError) {}")).len(),
        1
    );
    assert_eq!(
        violations(&f("runtime/x.rs", "use crate::sim::Plant;")).len(),
        1
    );
    assert_eq!(
        violations(&f("model/x.rs", "use crate::solver::Sqp;")).len(),
        1
    );
    assert!(violations(&f(
        "control/x.rs",
        "/// see [`crate::sim::Dof`]\nuse crate::model::Real;"
    ))
    .is_empty());
    assert!(violations(&f(
        "scenario/x.rs",
        "use crate::{config::Scenario, sim::Plant};"
    ))
    .is_empty());
}

/// Source text without line comments and without a trailing `#[cfg(test)] mod …` block.
fn code_of(text: &str) -> String {
    let lines: Vec<&str> = text.lines().collect();
    let end = (0..lines.len())
        .find(|&i| {
            lines[i].trim() == "#[cfg(test)]"
                && lines
                    .get(i + 1)
                    .is_some_and(|l| l.trim_start().starts_with("mod "))
        })
        .unwrap_or(lines.len());
    strip_comments(&lines[..end].join("\n"))
}

/// The first identifier of every item of the path that starts at `rest` (after `super::` or
/// `crate::module::`): `x` for `x::Y`, `a` and `B` for `{a::c, B}`.
fn path_heads(rest: &str) -> Vec<String> {
    let Some(group) = rest.strip_prefix('{') else {
        let name = ident_at(rest);
        return if name.is_empty() {
            Vec::new()
        } else {
            vec![name.to_string()]
        };
    };
    let mut out = Vec::new();
    let (mut depth, mut item_start) = (0usize, true);
    for (j, c) in group.char_indices() {
        match c {
            '{' => depth += 1,
            '}' if depth == 0 => break,
            '}' => depth -= 1,
            ',' if depth == 0 => item_start = true,
            c if item_start && (c.is_ascii_alphabetic() || c == '_') => {
                out.push(ident_at(&group[j..]).to_string());
                item_start = false;
            }
            _ => {}
        }
    }
    out
}

/// Heads of every path that starts with `prefix` in `code` (not inside a longer identifier or a
/// macro's `$crate`).
fn paths_after(code: &str, prefix: &str) -> Vec<String> {
    let mut out = Vec::new();
    for (i, _) in code.match_indices(prefix) {
        let prev = code[..i].chars().next_back().unwrap_or(' ');
        if prev.is_ascii_alphanumeric() || prev == '_' || prev == '$' {
            continue;
        }
        out.extend(path_heads(&code[i + prefix.len()..]));
    }
    out
}

/// Names a module root re-exports, mapped to the file they come from: `pub use x::{A, b::C}`
/// and `pub(crate) use x::A` give `A → x`, `C → x`.
fn reexports(root: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    for stmt in root.split(';') {
        let t = stmt.trim();
        let Some(rest) = t
            .strip_prefix("pub use ")
            .or_else(|| t.strip_prefix("pub(crate) use "))
        else {
            continue;
        };
        let file = ident_at(rest).to_string();
        let names = rest[file.len()..]
            .split(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
            .filter(|w| !w.is_empty() && *w != "self" && *w != "as");
        out.extend(names.map(|n| (n.to_string(), file.clone())));
    }
    out
}

/// The import edges between the files of each module: `(module, from, to)`.
fn file_edges(files: &[(String, String)]) -> Vec<(String, String, String)> {
    let mut edges = Vec::new();
    let modules: BTreeSet<&str> = files
        .iter()
        .filter_map(|(rel, _)| rel.split_once('/').map(|(m, _)| m))
        .collect();
    for m in modules {
        let root = files
            .iter()
            .find(|(rel, _)| *rel == format!("{m}/mod.rs") || *rel == format!("{m}.rs"));
        let exported = root
            .map(|(_, t)| reexports(&code_of(t)))
            .unwrap_or_default();
        let children: Vec<(&str, &str)> = files
            .iter()
            .filter_map(|(rel, t)| {
                let stem = rel.strip_prefix(&format!("{m}/"))?.strip_suffix(".rs")?;
                (stem != "mod" && !stem.contains('/')).then_some((stem, t.as_str()))
            })
            .collect();
        let resolve = |name: &str| -> Option<String> {
            if children.iter().any(|(s, _)| *s == name) {
                return Some(name.to_string());
            }
            exported
                .iter()
                .find(|(n, _)| n == name)
                .map(|(_, f)| f.clone())
        };
        for (stem, text) in &children {
            let code = code_of(text);
            let mut heads = paths_after(&code, "super::");
            heads.extend(paths_after(&code, &format!("crate::{m}::")));
            let targets: BTreeSet<String> = heads.iter().filter_map(|h| resolve(h)).collect();
            for t in targets.into_iter().filter(|t| t != stem) {
                edges.push((m.to_string(), stem.to_string(), t));
            }
        }
    }
    edges
}

/// The import circles, one per set of files, as `module: a → b → … → a`.
fn circles(edges: &[(String, String, String)]) -> Vec<String> {
    /// A path from `f` back to `start` (depth first, each file entered once).
    fn back_to<'a>(
        start: &str,
        f: &'a str,
        next: &dyn Fn(&str) -> Vec<&'a str>,
        seen: &mut BTreeSet<&'a str>,
    ) -> Option<Vec<&'a str>> {
        for g in next(f) {
            if g == start {
                return Some(vec![f]);
            }
            if seen.insert(g) {
                if let Some(mut p) = back_to(start, g, next, seen) {
                    p.insert(0, f);
                    return Some(p);
                }
            }
        }
        None
    }
    let mut found = Vec::new();
    let mut sets: Vec<(String, BTreeSet<String>)> = Vec::new();
    for (m, start, _) in edges {
        let next = |f: &str| -> Vec<&str> {
            edges
                .iter()
                .filter(|(mm, a, _)| mm == m && a == f)
                .map(|(_, _, b)| b.as_str())
                .collect()
        };
        let Some(mut path) = back_to(start, start, &next, &mut BTreeSet::new()) else {
            continue;
        };
        let set: BTreeSet<String> = path.iter().map(|s| s.to_string()).collect();
        if sets.iter().any(|(mm, s)| mm == m && *s == set) {
            continue;
        }
        sets.push((m.clone(), set));
        path.push(start);
        found.push(format!("{m}: {}", path.join(" → ")));
    }
    found
}

fn library_files() -> Vec<(String, String)> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut paths = Vec::new();
    rust_files(&src, &mut paths);
    paths
        .iter()
        .map(|p| {
            let rel = p
                .strip_prefix(&src)
                .unwrap()
                .to_string_lossy()
                .replace('\\', "/");
            (rel, std::fs::read_to_string(p).unwrap())
        })
        .collect()
}

#[test]
fn no_import_circle_between_files() {
    let files = library_files();
    let edges = file_edges(&files);
    assert!(edges.len() > 50, "found only {} file imports", edges.len());
    let found = circles(&edges);
    assert!(
        found.is_empty(),
        "import circles between files (move the shared piece where both can use it):\n{}",
        found.join("\n")
    );
}

#[test]
fn the_file_scan_finds_circles_through_files_and_reexports() {
    let f = |v: &[(&str, &str)]| -> Vec<(String, String)> {
        v.iter()
            .map(|(a, b)| (a.to_string(), b.to_string()))
            .collect()
    };
    // Direct: a uses b's file, b uses a's file.
    let direct = f(&[
        ("m/mod.rs", "mod a; mod b;"),
        ("m/a.rs", "use super::b::X;"),
        ("m/b.rs", "use super::{a::Y, Z};"),
    ]);
    assert_eq!(circles(&file_edges(&direct)), ["m: a → b → a"]);
    // Through the root's re-export and a `crate::m::` path; tests and comments do not count.
    let via_root = f(&[
        ("m/mod.rs", "mod a; mod b;\npub use b::{Bee, Other};"),
        ("m/a.rs", "fn f(x: crate::m::Bee) {}"),
        ("m/b.rs", "use super::a::Ay;"),
    ]);
    assert_eq!(circles(&file_edges(&via_root)).len(), 1);
    let one_way = f(&[
        ("m/mod.rs", "mod a; mod b;\npub use b::Bee;"),
        ("m/a.rs", "use super::Bee;"),
        (
            "m/b.rs",
            "// use super::a::Ay;\n#[cfg(test)]\nmod tests {\n    use super::super::a::Ay;\n}",
        ),
    ]);
    assert_eq!(file_edges(&one_way).len(), 1);
    assert!(circles(&file_edges(&one_way)).is_empty());
}
