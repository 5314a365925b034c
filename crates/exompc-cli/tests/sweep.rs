//! `exompc sweep` and `exompc plot` end to end, on short runs.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn exe() -> Command {
    Command::new(env!("CARGO_BIN_EXE_exompc"))
}

fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("exompc-sweep-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A short scenario: 1 s runs for both layouts.
fn short_config(dir: &Path) -> PathBuf {
    let p = dir.join("short.toml");
    std::fs::write(
        &p,
        "[timing]\nduration_2dof_s = 1.0\nduration_1dof_s = 1.0\n",
    )
    .unwrap();
    p
}

fn run_ok(cmd: &mut Command) -> Output {
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "exit {:?}\nstdout: {}\nstderr: {}",
        out.status.code(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn sweep(dir: &Path, out: &str, extra: &[&str]) -> serde_json::Value {
    let cfg = short_config(dir);
    let out_dir = dir.join(out);
    run_ok(
        exe()
            .arg("sweep")
            .arg("--config")
            .arg(&cfg)
            .args(["--payloads", "0:1:2", "--quiet", "--out"])
            .arg(&out_dir)
            .args(extra),
    );
    let text = std::fs::read_to_string(out_dir.join("sweep.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

/// The rows with the wall-clock-dependent step times removed.
fn without_timing(v: &serde_json::Value) -> serde_json::Value {
    let mut v = v.clone();
    for r in v["rows"].as_array_mut().unwrap() {
        r.as_object_mut().unwrap().remove("step_time_us");
    }
    v
}

#[test]
fn sweep_writes_table_json_and_traces() {
    let dir = temp_dir("layout");
    let v = sweep(&dir, "sw", &[]);
    let rows = v["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 6, "3 payloads × 2 controllers");
    let out = dir.join("sw");
    for c in ["nmpc", "msnmpc"] {
        for p in ["0", "1", "2"] {
            let run = out.join(format!("{c}_{p}kg"));
            let trace = std::fs::read_to_string(run.join("trace.csv")).unwrap();
            assert!(trace.lines().count() > 10, "{} has rows", run.display());
            assert!(run.join("summary.json").is_file());
            assert!(rows.iter().any(|r| r["controller"] == c
                && (r["payload_kg"].as_f64().unwrap() - p.parse::<f64>().unwrap()).abs() < 1e-12));
        }
    }
    let table = std::fs::read_to_string(out.join("table2.md")).unwrap();
    assert!(table.contains("MS-NMPC RMS F thigh (N)"), "{table}");
    assert!(table.contains("| 2.00 |"), "{table}");
    assert_eq!(table.lines().count(), 2 + 3);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn sweep_is_deterministic() {
    let dir = temp_dir("determinism");
    let a = sweep(&dir, "a", &["--json"]);
    let b = sweep(&dir, "b", &["--json"]);
    assert_eq!(without_timing(&a), without_timing(&b));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn sweep_one_dof_has_dashes_for_the_hip() {
    let dir = temp_dir("onedof");
    let v = sweep(&dir, "sw", &["--dof", "1", "--controllers", "msnmpc"]);
    assert_eq!(v["rows"].as_array().unwrap().len(), 3);
    let table = std::fs::read_to_string(dir.join("sw/table2.md")).unwrap();
    assert!(table.contains("| – |"), "{table}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_payloads_exit_2_naming_the_flag() {
    let dir = temp_dir("bad");
    for bad in ["abc", "0:0:1", "2:0.5:1", "0,,1", "-1"] {
        let out = exe()
            .args(["sweep", "--quiet", "--payloads", bad, "--out"])
            .arg(dir.join("o"))
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(2), "--payloads {bad}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("--payloads"), "--payloads {bad}: {err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

fn assert_figure(path: &Path) {
    let len = std::fs::metadata(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .len();
    assert!(len > 1000, "{} is {len} bytes", path.display());
}

#[test]
fn plot_simulate_folder_writes_png_and_svg() {
    let dir = temp_dir("plot");
    let cfg = short_config(&dir);
    let out = dir.join("sim");
    run_ok(
        exe()
            .arg("simulate")
            .arg("--config")
            .arg(&cfg)
            .arg("--out")
            .arg(&out),
    );
    run_ok(exe().arg("plot").arg(&out));
    for stem in ["states", "interaction"] {
        assert_figure(&out.join(format!("{stem}.png")));
        assert_figure(&out.join(format!("{stem}.svg")));
    }
    let png = std::fs::read(out.join("states.png")).unwrap();
    assert_eq!(&png[1..4], b"PNG");
    let svg = std::fs::read_to_string(out.join("states.svg")).unwrap();
    assert!(svg.contains("<svg"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn plot_sweep_folder_writes_comparison_figures() {
    let dir = temp_dir("plotsweep");
    sweep(&dir, "sw", &["--plot"]);
    let out = dir.join("sw");
    for stem in [
        "payload_sweep",
        "compare_2kg",
        "compare_0kg",
        "states_msnmpc_2kg",
        "step_time_2kg",
    ] {
        assert_figure(&out.join(format!("{stem}.png")));
        assert_figure(&out.join(format!("{stem}.svg")));
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn plot_empty_folder_is_a_usage_error() {
    let dir = temp_dir("empty");
    let out = exe().arg("plot").arg(&dir).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    let _ = std::fs::remove_dir_all(&dir);
}
