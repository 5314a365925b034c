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

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The layers, lowest first. A module may import modules of strictly lower layers only.
const LAYERS: &[&[&str]] = &[
    &["check", "test_rng"],
    &["model", "solver"],
    &["estimate"],
    &["control"],
    &["sim"],
    &["runtime"],
    &["config"],
    &["scenario"],
];

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
