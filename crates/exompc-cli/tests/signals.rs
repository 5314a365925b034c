//! SIGINT/SIGTERM on the offline commands (issue 29 item 6): each of `simulate`, `sweep`,
//! `soak`, `envelope` and `bench`, signalled mid-run, stops promptly (checked per control
//! step), keeps what it completed marked partial, and exits 130 (SIGINT) or 143 (SIGTERM).
//! The time bound is generous (10 s): it checks the behaviour, not the speed.
#![cfg(unix)]

mod common;

use common::fresh_dir;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Longest wait for a run to get under way, and for it to end after the signal.
const WAIT: Duration = Duration::from_secs(10);

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// Names in `dir` (sorted; empty when it does not exist).
fn entries(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|r| {
            r.filter_map(Result::ok)
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// Starts exompc with `args`, waits until `started()` holds (at most [`WAIT`]) and then
/// at least `min_delay`, sends `sig`, and returns the output and the time from the signal to
/// the exit.
fn signalled(
    args: &[&str],
    sig: libc::c_int,
    min_delay: Duration,
    started: impl Fn() -> bool,
) -> (Output, Duration) {
    let child = Command::new(env!("CARGO_BIN_EXE_exompc"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    while !(started() && t0.elapsed() >= min_delay) && t0.elapsed() < WAIT {
        std::thread::sleep(Duration::from_millis(20));
    }
    let sent = Instant::now();
    // SAFETY: plain kill(2) on our own child.
    unsafe {
        libc::kill(child.id() as libc::pid_t, sig);
    }
    let out = child.wait_with_output().unwrap();
    (out, sent.elapsed())
}

/// Whether `dir` holds an entry whose name starts with `prefix` (a streamed temporary file).
fn has(dir: &Path, prefix: &str) -> bool {
    entries(dir).iter().any(|n| n.starts_with(prefix))
}

fn json(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap()
}

#[test]
fn simulate_keeps_its_partial_trace_and_summary() {
    let dir = fresh_dir("sig_simulate");
    let d = dir.to_str().unwrap();
    let (out, took) = signalled(
        &["simulate", "--duration", "3000", "--out", d],
        libc::SIGINT,
        Duration::from_millis(300),
        || has(&dir, ".trace.csv.tmp"),
    );
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{err}");
    assert!(took < WAIT, "took {took:?}");
    assert!(err.contains("interrupted by SIGINT"), "{err}");
    assert!(err.contains("partial results kept"), "{err}");
    assert_eq!(entries(&dir), ["summary.json", "trace.csv"]);
    let s = json(&dir.join("summary.json"));
    assert_eq!(s["partial"], true);
    let done = s["completed_steps"].as_u64().unwrap();
    assert_eq!(s["planned_steps"], 300_000);
    assert!(done > 0 && done < 300_000, "{done}");
    assert_eq!(s["steps"].as_u64(), Some(done));
    // The trace holds exactly the steps the summary covers (header + one row per step).
    let rows = std::fs::read_to_string(dir.join("trace.csv"))
        .unwrap()
        .lines()
        .count();
    assert_eq!(rows as u64, done + 1);

    // SIGTERM during the set-up (the identifiability check, long with a tiny dt) ends it
    // too: 143, and no output folder left behind.
    let cfg = fresh_dir("sig_simulate_tiny_dt.toml");
    std::fs::write(&cfg, "[timing]\ndt = 1e-6\n").unwrap();
    let dir = fresh_dir("sig_simulate_setup");
    let (out, took) = signalled(
        &[
            "simulate",
            "--config",
            cfg.to_str().unwrap(),
            "--out",
            dir.to_str().unwrap(),
        ],
        libc::SIGTERM,
        Duration::from_millis(1500),
        || true,
    );
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(143), "{err}");
    assert!(took < WAIT, "took {took:?}");
    assert!(!dir.exists(), "{err}");
}

#[test]
fn sweep_keeps_its_completed_runs_marked_partial() {
    let dir = fresh_dir("sig_sweep");
    let d = dir.to_str().unwrap();
    let (out, took) = signalled(
        &[
            "sweep",
            "--payloads",
            "0,1,2",
            "--controllers",
            "nmpc",
            "--duration",
            "3000",
            "--quiet",
            "--out",
            d,
        ],
        libc::SIGTERM,
        Duration::from_millis(300),
        || has(&dir, ".nmpc_"),
    );
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(143), "{err}");
    assert!(took < WAIT, "took {took:?}");
    assert!(err.contains("0 of 3 runs completed"), "{err}");
    // No half-written run folder; the (empty) table and sweep.json say partial.
    assert_eq!(entries(&dir), ["sweep.json", "table2.md"]);
    assert_eq!(json(&dir.join("sweep.json"))["partial"], true);
    let table = std::fs::read_to_string(dir.join("table2.md")).unwrap();
    assert!(table.contains("Partial"), "{table}");
}

#[test]
fn soak_keeps_its_partial_report() {
    let dir = fresh_dir("sig_soak");
    let d = dir.to_str().unwrap();
    let (out, took) = signalled(
        &["soak", "--hours", "10", "--trace-every", "100", "--out", d],
        libc::SIGTERM,
        Duration::from_millis(500),
        || has(&dir, ".soak_trace.csv.tmp"),
    );
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(143), "{err}");
    assert!(took < WAIT, "took {took:?}");
    assert!(
        text(&out.stdout).contains("partial"),
        "{}",
        text(&out.stdout)
    );
    assert_eq!(entries(&dir), ["soak.json", "soak_trace.csv"]);
    let r = json(&dir.join("soak.json"));
    assert_eq!(r["partial"], true);
    assert_eq!(r["planned_s"], 36000.0);
    let simulated = r["simulated_s"].as_f64().unwrap();
    assert!(simulated > 0.0 && simulated < 36000.0, "{simulated}");
}

#[test]
fn envelope_keeps_its_partial_scan() {
    let dir = fresh_dir("sig_envelope");
    let d = dir.to_str().unwrap();
    let (out, took) = signalled(
        &[
            "envelope",
            "--set",
            "timing.duration_2dof_s=3000",
            "--payloads",
            "0",
            "--controllers",
            "nmpc",
            "--quiet",
            "--out",
            d,
        ],
        libc::SIGINT,
        Duration::from_millis(1500),
        || true,
    );
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{err}");
    assert!(took < WAIT, "took {took:?}");
    assert!(err.contains("0 of 1 runs completed"), "{err}");
    let env = json(&dir.join("envelope.json"));
    assert_eq!(env["partial"], true);
    assert_eq!(env["runs"][0]["error"], "not run (interrupted)");
    let md = std::fs::read_to_string(dir.join("envelope.md")).unwrap();
    assert!(md.starts_with("Partial"), "{md}");
}

#[test]
fn bench_reports_partial_timings() {
    let (out, took) = signalled(
        &["bench", "--json", "--steps", "1000000"],
        libc::SIGINT,
        Duration::from_millis(1500),
        || true,
    );
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{err}");
    assert!(took < WAIT, "took {took:?}");
    let report: serde_json::Value = serde_json::from_str(text(&out.stdout).trim()).unwrap();
    assert_eq!(report["partial"], true);
    let steps = report["nmpc"]["steps"].as_u64().unwrap();
    assert!(steps > 0 && steps < 1_000_000, "{steps}");
}
