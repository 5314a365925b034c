//! Structure check of the CLI crate (docs/ARCHITECTURE.md, "Layers"): subcommands are leaves.
//!
//! A plain text scan: the binary's modules are the `mod name;` lines of `src/main.rs`, the
//! library's the `pub mod name;` lines of `src/lib.rs`. In each module's file (line comments
//! removed) every `crate::name` or `crate::{name, …}` is an edge to module `name` of the same
//! target, or to the binary's root `main` when `name` is not a module (an item defined in
//! `main.rs`). `main.rs` uses all of the binary's modules. Rules:
//! - a command module (every binary module but the shared ones in [`SHARED`]) uses no other
//!   command module and nothing of `main.rs`; shared modules use no command module either;
//! - no circle among the modules of either target.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Binary modules shared by several subcommands; every other binary module is a command.
const SHARED: &[&str] = &["args", "plot"];

fn strip_comments(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for line in text.lines() {
        out.push_str(line.split("//").next().unwrap_or(""));
        out.push('\n');
    }
    out
}

fn leading_ident(s: &str) -> String {
    s.chars()
        .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
        .collect()
}

/// First names of every `crate::…` path in `text` (comments removed).
fn crate_names(text: &str) -> BTreeSet<String> {
    let mut names = BTreeSet::new();
    let mut rest = text;
    while let Some(i) = rest.find("crate::") {
        let boundary = rest[..i]
            .chars()
            .next_back()
            .is_none_or(|c| !(c.is_ascii_alphanumeric() || c == '_'));
        rest = &rest[i + "crate::".len()..];
        if !boundary {
            continue;
        }
        match rest.strip_prefix('{') {
            Some(group) => {
                let body = &group[..group.find('}').unwrap_or(group.len())];
                names.extend(
                    body.split(',')
                        .map(|item| leading_ident(item.trim()))
                        .filter(|n| !n.is_empty()),
                );
            }
            None => {
                names.insert(leading_ident(rest));
            }
        }
    }
    names.remove("");
    names
}

/// Module names declared in `root` with `prefix` (`"mod "` or `"pub mod "`).
fn declared(root: &str, prefix: &str) -> Vec<String> {
    root.lines()
        .filter_map(|l| l.trim().strip_prefix(prefix))
        .filter_map(|m| m.strip_suffix(';'))
        .map(str::to_string)
        .collect()
}

type Graph = BTreeMap<String, BTreeSet<String>>;

/// Edges of one target: `modules` with their source text; names that are not modules map to
/// `root`.
fn graph(modules: &[(String, String)], root: &str) -> Graph {
    let names: BTreeSet<&str> = modules.iter().map(|(m, _)| m.as_str()).collect();
    modules
        .iter()
        .map(|(m, text)| {
            let used = crate_names(&strip_comments(text))
                .into_iter()
                .map(|n| {
                    if names.contains(n.as_str()) {
                        n
                    } else {
                        root.to_string()
                    }
                })
                .filter(|n| n != m)
                .collect();
            (m.clone(), used)
        })
        .collect()
}

/// One circle of `g`, if any (depth-first search).
fn find_circle(g: &Graph) -> Option<Vec<String>> {
    fn visit(
        g: &Graph,
        n: &str,
        stack: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) -> Option<Vec<String>> {
        if let Some(i) = stack.iter().position(|s| s == n) {
            let mut c = stack[i..].to_vec();
            c.push(n.to_string());
            return Some(c);
        }
        if done.contains(n) {
            return None;
        }
        stack.push(n.to_string());
        for m in g.get(n).into_iter().flatten() {
            if let Some(c) = visit(g, m, stack, done) {
                return Some(c);
            }
        }
        stack.pop();
        done.insert(n.to_string());
        None
    }
    let mut done = BTreeSet::new();
    g.keys()
        .find_map(|n| visit(g, n, &mut Vec::new(), &mut done))
}

/// Rule violations of the binary's graph `g` (which includes `main`).
fn leaf_violations(g: &Graph) -> Vec<String> {
    let is_command = |m: &str| m != "main" && !SHARED.contains(&m);
    let mut bad = Vec::new();
    for (m, used) in g {
        if m == "main" {
            continue;
        }
        for u in used {
            if u == "main" || is_command(u) {
                bad.push(format!("`{m}` uses `crate::{u}`"));
            }
        }
    }
    bad
}

fn read_target(src: &Path, root_file: &str, prefix: &str) -> (String, Vec<(String, String)>) {
    let root = std::fs::read_to_string(src.join(root_file)).unwrap();
    let modules = declared(&root, prefix)
        .into_iter()
        .map(|m| {
            let text = std::fs::read_to_string(src.join(format!("{m}.rs"))).unwrap();
            (m, text)
        })
        .collect();
    (root, modules)
}

#[test]
fn commands_are_leaves_and_there_is_no_circle() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let (main_text, bin) = read_target(&src, "main.rs", "mod ");
    assert!(bin.len() >= 8, "found only {} binary modules", bin.len());
    let mut g = graph(&bin, "main");
    g.insert(
        "main".into(),
        bin.iter().map(|(m, _)| m.clone()).collect::<BTreeSet<_>>(),
    );
    assert!(!main_text.is_empty());
    let bad = leaf_violations(&g);
    assert!(
        bad.is_empty(),
        "command modules must be leaves:\n{}",
        bad.join("\n")
    );
    assert_eq!(find_circle(&g), None, "import circle in the binary");

    let (_, lib) = read_target(&src, "lib.rs", "pub mod ");
    assert!(lib.len() >= 5, "found only {} library modules", lib.len());
    assert_eq!(
        find_circle(&graph(&lib, "lib")),
        None,
        "import circle in the library"
    );
}

/// Issue 31.3: what a library user needs is outside the binary's crate: the Python package,
/// the fuzz targets and `exompc-study` do not depend on `exompc-cli`, and `exompc-study` has no
/// import circle.
#[test]
fn python_and_fuzz_do_not_depend_on_the_cli_crate() {
    let crates = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    for manifest in [
        "exompc-py/Cargo.toml",
        "exompc-study/Cargo.toml",
        "../fuzz/Cargo.toml",
    ] {
        let text = std::fs::read_to_string(crates.join(manifest)).unwrap();
        let deps: Vec<&str> = text
            .lines()
            .map(str::trim)
            .filter(|l| !l.starts_with('#'))
            .filter(|l| l.starts_with("exompc"))
            .collect();
        assert!(
            deps.iter().any(|l| l.starts_with("exompc ")),
            "{manifest} must depend on the library: {deps:?}"
        );
        assert!(
            deps.iter().all(|l| !l.starts_with("exompc-cli")),
            "{manifest} depends on the CLI crate: {deps:?}"
        );
    }
    let src = crates.join("exompc-study/src");
    let (_, study) = read_target(&src, "lib.rs", "pub mod ");
    assert!(study.len() >= 5, "found only {} modules", study.len());
    assert_eq!(
        find_circle(&graph(&study, "lib")),
        None,
        "import circle in exompc-study"
    );
}

#[test]
fn the_scan_finds_command_imports_and_circles() {
    let m = |name: &str, text: &str| (name.to_string(), text.to_string());
    let bin = [
        m("args", "use exompc_cli::io;"),
        m(
            "simulate",
            "use crate::args::ConfigOpt;\nuse crate::sweep::x; // crate::plot",
        ),
        m("sweep", "use crate::{args::A, simulate::apply};"),
        m("solve", "use crate::Cli;"),
    ];
    let g = graph(&bin, "main");
    let bad = leaf_violations(&g);
    assert_eq!(
        bad,
        [
            "`simulate` uses `crate::sweep`",
            "`solve` uses `crate::main`",
            "`sweep` uses `crate::simulate`",
        ]
    );
    let circle = find_circle(&g).unwrap();
    assert!(circle.contains(&"sweep".to_string()) && circle.contains(&"simulate".to_string()));
    assert_eq!(find_circle(&graph(&bin[..1], "main")), None);
}
