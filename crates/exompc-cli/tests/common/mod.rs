//! Helpers shared by the CLI integration tests: run the `exompc` binary, scratch paths.
#![allow(dead_code)]

use std::io::Write;
use std::path::PathBuf;
use std::process::{Command, Output, Stdio};

/// Run the `exompc` binary built for these tests with `args`.
pub fn exompc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_exompc"))
        .args(args)
        .output()
        .expect("run exompc")
}

/// Run the `exompc` binary with `args`, writing `stdin` to its standard input.
pub fn exompc_stdin(args: &[&str], stdin: &str) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_exompc"))
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn exompc");
    child
        .stdin
        .take()
        .unwrap()
        .write_all(stdin.as_bytes())
        .unwrap();
    child.wait_with_output().unwrap()
}

/// A path `name` in this test binary's own scratch folder (`exompc-<test>-tests` below
/// cargo's target tmp dir), created if missing.
pub fn scratch(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("exompc-{}-tests", env!("CARGO_CRATE_NAME")));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// `scratch(name)` with anything already there removed.
pub fn fresh_dir(name: &str) -> PathBuf {
    let d = scratch(name);
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// The process's standard error as text.
pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// `fresh_dir(name)`, created empty.
pub fn empty_dir(name: &str) -> PathBuf {
    let d = fresh_dir(name);
    std::fs::create_dir_all(&d).unwrap();
    d
}
