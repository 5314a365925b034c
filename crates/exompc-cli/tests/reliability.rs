//! Reliability of the `exompc` binary: bad configs rejected naming the field (extending
//! `tests/cli.rs`), fault-injected runs within limits, clear output-folder errors, and no
//! truncated result files after an interrupted write.

use exompc_cli::io::AtomicWriter;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

mod common;
use common::{exompc, fresh_dir, scratch, stderr};

fn with_config(name: &str, toml: &str) -> PathBuf {
    let path = scratch(name);
    std::fs::write(&path, toml).unwrap();
    path
}

#[test]
fn more_bad_configs_exit_2_naming_the_field() {
    let ev = |extra: &str| {
        format!(
            "[[faults.events]]\nkind = \"nan\"\nchannel = \"f2\"\nstart_s = 1.0\nduration_s = 0.1\n{extra}"
        )
    };
    let cases: Vec<(&str, String, Vec<&str>)> = vec![
        // Negative masses elsewhere than tests/cli.rs.
        (
            "neg_shank.toml",
            "[robot.shank]\nmass_kg = -0.5\n".into(),
            vec!["robot.shank.mass_kg"],
        ),
        (
            "neg_body.toml",
            "[human]\nbody_mass_kg = -70\n".into(),
            vec!["human.body_mass_kg"],
        ),
        // Zero periods.
        (
            "zero_freq_period.toml",
            "[trajectory]\nfrequency_period_s = 0.0\n".into(),
            vec!["trajectory.frequency_period_s"],
        ),
        (
            "zero_substeps.toml",
            "[timing]\nplant_substeps = 0\n".into(),
            vec!["timing.plant_substeps"],
        ),
        // NaN gains.
        (
            "nan_k1.toml",
            "[controller]\nk1 = nan\n".into(),
            vec!["controller.k1"],
        ),
        (
            "nan_c1.toml",
            "[multistage]\nc1 = nan\n".into(),
            vec!["multistage.c1"],
        ),
        (
            "nan_rd.toml",
            "[controller]\nr_d = -nan\n".into(),
            vec!["controller.r_d"],
        ),
        // Unknown keys in the safety sections.
        (
            "unknown_monitor.toml",
            "[monitors]\nforce_max = 50.0\n".into(),
            vec!["`force_max`", "[monitors]", "did you mean `force_max_n`"],
        ),
        (
            "unknown_faults.toml",
            "[faults]\nsaturation = 60.0\n".into(),
            vec!["`saturation`", "[faults]", "did you mean `saturation_n`"],
        ),
        // Payload lists.
        (
            "neg_payload_entry.toml",
            "[multistage]\npayloads_kg = [0.0, -1.0]\n".into(),
            vec!["multistage.payloads_kg"],
        ),
        // Faults and monitors.
        (
            "fault_neg_start.toml",
            ev("").replace("start_s = 1.0", "start_s = -1.0"),
            vec!["faults.events[0].start_s"],
        ),
        (
            "fault_nan_mag.toml",
            ev("magnitude = nan\n"),
            vec!["faults.events[0].magnitude"],
        ),
        (
            "fault_channel.toml",
            ev("").replace("\"f2\"", "\"f3\""),
            vec!["channel"],
        ),
        (
            "fault_kind.toml",
            ev("").replace("\"nan\"", "\"glitch\""),
            vec!["kind"],
        ),
        (
            "saturation.toml",
            "[faults]\nsaturation_n = 0.0\n".into(),
            vec!["faults.saturation_n"],
        ),
        (
            "monitor_force.toml",
            "[monitors]\nforce_max_n = -5.0\n".into(),
            vec!["monitors.force_max_n"],
        ),
        (
            "monitor_timeout.toml",
            "[monitors]\nsensor_timeout_s = inf\n".into(),
            vec!["monitors.sensor_timeout_s"],
        ),
        (
            "monitor_response.toml",
            "[monitors]\nresponse = \"panic\"\n".into(),
            vec!["response"],
        ),
    ];
    for (name, toml, needles) in &cases {
        let path = with_config(name, toml);
        let out = exompc(&[
            "simulate",
            "--config",
            path.to_str().unwrap(),
            "--out",
            fresh_dir("never").to_str().unwrap(),
        ]);
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(2), "{name}: {err}");
        assert!(err.starts_with("error: "), "{name}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{name}: {err}");
        for n in needles {
            assert!(err.contains(n), "{name}: `{n}` not in: {err}");
        }
    }
}

const FAULTS: &str = r#"
[[faults.events]]
kind = "nan"
channel = "f1"
start_s = 0.3
duration_s = 0.1

[[faults.events]]
kind = "inf"
channel = "qd2"
start_s = 0.6
duration_s = 0.05

[[faults.events]]
kind = "dropout"
channel = "q1"
start_s = 0.9
duration_s = 0.2

[[faults.events]]
kind = "spike"
channel = "f2"
start_s = 1.2
duration_s = 0.05
magnitude = 500.0

[[faults.events]]
kind = "stuck"
channel = "qd1"
start_s = 1.4
duration_s = 0.2

[[faults.events]]
kind = "saturation"
channel = "f2"
start_s = 1.7
duration_s = 0.1
"#;

fn summary(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("summary.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

#[test]
fn fault_schedule_runs_within_limits() {
    let cfg = with_config("faults.toml", FAULTS);
    for (controller, dof) in [("msnmpc", "2"), ("nmpc", "2"), ("pd", "2"), ("msnmpc", "1")] {
        let out_dir = fresh_dir(&format!("faults-{controller}-{dof}"));
        let out = exompc(&[
            "simulate",
            "--config",
            cfg.to_str().unwrap(),
            "--controller",
            controller,
            "--dof",
            dof,
            "--duration",
            "2.5",
            "--json",
            "--out",
            out_dir.to_str().unwrap(),
        ]);
        assert!(out.status.success(), "{controller}/{dof}: {}", stderr(&out));
        let s = summary(&out_dir);
        assert_eq!(s["limit_violations"], 0, "{controller}/{dof}: {s}");
        assert_eq!(s["steps"], 250);
        let trace = std::fs::read_to_string(out_dir.join("trace.csv")).unwrap();
        // The measured (filtered) force may be NaN during a fault; the torque never is.
        let mut lines = trace.lines();
        let header: Vec<&str> = lines.next().unwrap().split(',').collect();
        let cols: Vec<usize> = (0..header.len())
            .filter(|&i| header[i].starts_with("torque_robot") || header[i].starts_with("q_robot"))
            .collect();
        assert!(!cols.is_empty());
        for l in lines {
            let f: Vec<&str> = l.split(',').collect();
            for &i in &cols {
                let v: f64 = f[i].parse().unwrap();
                assert!(v.is_finite(), "{controller}/{dof}: {} = {v}", header[i]);
            }
        }
        // The faults are visible in the status column.
        assert!(
            trace.contains("bad_measurement") || trace.contains("monitor_tripped"),
            "{controller}/{dof}: no fault visible in the trace"
        );
        if dof == "2" {
            assert!(
                trace.contains("monitor_tripped"),
                "{controller}: no monitor trip"
            );
        }
    }
}

/// The soak's report says whether and why its supervisor latched (issue 28): the clean
/// default soak does not (`not latched`, `latched_at_s` null), and a soak whose strap-force
/// monitor trips on the gait itself (`force_max_n` 1 N) with `latch_trips = 1` latches on its
/// first handover, by `strap_force`, in the printed line and in `soak.json`.
#[test]
fn soak_reports_whether_and_why_it_latched() {
    let out_dir = fresh_dir("soak_latch_none");
    let args = |dir: &Path| {
        vec![
            "soak".to_string(),
            "--hours".into(),
            "0.002".into(),
            "--out".into(),
            dir.to_str().unwrap().into(),
        ]
    };
    let argv = args(&out_dir);
    let out = exompc(&argv.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(out.status.success(), "{}", stderr(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("  not latched"), "{stdout}");
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("soak.json")).unwrap()).unwrap();
    assert!(r["latched_at_s"].is_null(), "{r}");
    // Its one fault (NaN on f1 at 5 s) is judged against the fault-free run and passes.
    assert_eq!(r["fault_episodes"], 1, "{r}");
    assert_eq!(r["fault_episodes_passing"], 1, "{r}");
    assert_eq!(r["fault_classes"][0]["fault"], "nan f1", "{r}");
    assert_eq!(r["fault_classes"][0]["peak_goal_n"], 12.0, "{r}");

    let cfg = with_config(
        "soak_latch.toml",
        "[monitors]\nforce_max_n = 1.0\nlatch_trips = 1\n",
    );
    let out_dir = fresh_dir("soak_latch");
    let mut argv = args(&out_dir);
    argv.extend(["--config".to_string(), cfg.to_str().unwrap().to_string()]);
    let out = exompc(&argv.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(out.status.success(), "{}", stderr(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("LATCHED at") && stdout.contains("by strap_force after 1 handovers"),
        "{stdout}"
    );
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("soak.json")).unwrap()).unwrap();
    assert!(r["latched_at_s"].as_f64().is_some(), "{r}");
    assert_eq!(r["latched_by"], "strap_force", "{r}");
    assert_eq!(r["handovers"], 1, "{r}");
    assert!(r["latched_for_s"].as_f64().unwrap() > 0.0, "{r}");
    // A fault after the latch fails its goals (no latch), and the verdict says so.
    assert_eq!(r["fault_episodes"], 1, "{r}");
    assert_eq!(r["fault_episodes_passing"], 0, "{r}");
    assert!(
        stdout.contains("1 of 1 fault episodes over issue 28's goals (nan f1)"),
        "{stdout}"
    );
}

#[test]
fn soak_writes_its_report() {
    let out_dir = fresh_dir("soak");
    let out = exompc(&[
        "soak",
        "--hours",
        "0.005",
        "--trace-every",
        "100",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = std::fs::read_to_string(out_dir.join("soak.json")).unwrap();
    let r: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(r["steps"], 1800);
    assert_eq!(r["limit_violations"], 0);
    assert_eq!(r["nan_count"], 0);
    for key in [
        "max_abs_force_n",
        "rms_force_n",
        "solver_failures",
        "monitor_trips",
        "wall_time_s",
    ] {
        assert!(r.get(key).is_some(), "{key} missing: {text}");
    }
    assert!(String::from_utf8_lossy(&out.stdout).contains("limit violations 0"));
    assert!(
        String::from_utf8_lossy(&out.stdout)
            .contains("fault episodes within issue 28's goals: 2 of 2"),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    let trace = std::fs::read_to_string(out_dir.join("soak_trace.csv")).unwrap();
    assert_eq!(
        trace.lines().count(),
        1 + 18,
        "header + every 100th of 1800 steps"
    );
    let bad = exompc(&["soak", "--hours", "0"]);
    assert_eq!(bad.status.code(), Some(2));
    assert!(stderr(&bad).contains("--hours"));
    let bad = exompc(&["soak", "--hours", "1000"]);
    assert_eq!(bad.status.code(), Some(2));
    assert!(stderr(&bad).contains("--hours"), "{}", stderr(&bad));
    let bad = exompc(&["soak", "--payload", "30"]);
    assert_eq!(bad.status.code(), Some(2));
    assert!(stderr(&bad).contains("payload"));
}

#[test]
fn unwritable_out_is_a_clear_error() {
    let file = scratch("plain-file");
    std::fs::write(&file, "x").unwrap();
    for (cmd, out) in [
        ("simulate", file.clone()),
        ("simulate", file.join("sub")),
        ("soak", file.join("sub")),
    ] {
        let mut args = vec![cmd, "--out", out.to_str().unwrap()];
        if cmd == "soak" {
            args.extend(["--hours", "0.001"]);
        }
        let o = exompc(&args);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{cmd} {}: {err}", out.display());
        assert!(err.starts_with("error: "), "{err}");
        assert!(err.contains(out.to_str().unwrap()), "path not named: {err}");
        assert!(
            err.contains("not a folder") || err.contains("cannot create output folder"),
            "{err}"
        );
    }
}

fn leftovers(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect()
}

#[test]
fn atomic_writer_dropped_without_finish_leaves_nothing() {
    let dir = fresh_dir("atomic");
    std::fs::create_dir_all(&dir).unwrap();
    let dest = dir.join("result.csv");
    {
        let mut w = AtomicWriter::create(&dest).unwrap();
        w.write_all(&vec![b'x'; 1 << 20]).unwrap();
        // Dropped mid-write (an error or a panic unwinding).
    }
    assert!(!dest.exists());
    assert!(leftovers(&dir).is_empty(), "{:?}", leftovers(&dir));

    // An existing result survives an interrupted rewrite unchanged.
    std::fs::write(&dest, "old complete\n").unwrap();
    {
        let mut w = AtomicWriter::create(&dest).unwrap();
        w.write_all(b"new partial").unwrap();
    }
    assert_eq!(std::fs::read_to_string(&dest).unwrap(), "old complete\n");
    assert_eq!(leftovers(&dir), ["result.csv"]);

    // A panic while writing also cleans up.
    let d2 = dest.clone();
    let r = std::panic::catch_unwind(move || {
        let mut w = AtomicWriter::create(&d2.with_file_name("panic.csv")).unwrap();
        w.write_all(b"partial").unwrap();
        panic!("interrupted");
    });
    assert!(r.is_err());
    assert_eq!(leftovers(&dir), ["result.csv"]);

    // And a finished one is complete.
    let mut w = AtomicWriter::create(&dest).unwrap();
    w.write_all(b"new complete\n").unwrap();
    w.finish().unwrap();
    assert_eq!(std::fs::read_to_string(&dest).unwrap(), "new complete\n");
}

#[test]
fn killed_run_leaves_no_truncated_results() {
    let out_dir = fresh_dir("killed");
    let mut child = Command::new(env!("CARGO_BIN_EXE_exompc"))
        .args([
            "simulate",
            "--duration",
            "3600",
            "--out",
            out_dir.to_str().unwrap(),
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // Wait until the run is streaming its trace (a temporary file exists), then kill it.
    let mut streaming = false;
    for _ in 0..400 {
        if out_dir.exists() && leftovers(&out_dir).iter().any(|n| n.contains(".tmp.")) {
            streaming = true;
            break;
        }
        if child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(Duration::from_millis(25));
    }
    let _ = child.kill();
    let _ = child.wait();
    assert!(streaming, "the run never started streaming");
    // Only hidden temporaries may remain; never a partial trace.csv / summary.json.
    assert!(!out_dir.join("trace.csv").exists());
    assert!(!out_dir.join("summary.json").exists());
}

/// The arguments of `exompc faults` on one cell: a 60-ms fault of `kind` on `group` at 0 kg,
/// 4-s runs, results in `out`.
fn one_cell_fault_scan<'a>(kind: &'a str, group: &'a str, out: &'a str) -> [&'a str; 13] {
    [
        "faults",
        "--kinds",
        kind,
        "--groups",
        group,
        "--durations",
        "0.06",
        "--payloads",
        "0",
        "--run-s",
        "4",
        "--out",
        out,
    ]
}

/// `exompc faults --groups` takes one joint's encoder (`joint1`: the hip's angle and
/// velocity) as a group, named so in the table; an unknown group is refused (exit 2) naming
/// what was typed and every group.
#[test]
fn fault_scan_groups_include_one_joints_encoder() {
    let dir = fresh_dir("fault-scan-joint");
    let d = dir.to_str().unwrap();
    let bad = exompc(&["faults", "--groups", "joint3", "--out", d]);
    assert_eq!(bad.status.code(), Some(2), "{}", stderr(&bad));
    let e = stderr(&bad);
    assert!(
        e.contains("`joint3`") && e.contains("forces, joint1, joint2"),
        "{e}"
    );
    let out = exompc(&one_cell_fault_scan("dropout", "joint1", d));
    assert!(out.status.success(), "{}", stderr(&out));
    let md = std::fs::read_to_string(dir.join("faults.md")).unwrap();
    assert!(md.contains("| dropout | joint1 | 0.06 |"), "{md}");
}

/// `exompc faults` on a one-cell grid (a 60-ms NaN on the strap forces, 4-s runs): the table,
/// the JSON and the heat map (a PNG and an SVG naming the row) are written; a second scan into
/// the same folder without `--force` is refused (exit 2) and leaves the results as they were.
#[test]
fn fault_scan_writes_table_json_and_heat_map() {
    let dir = fresh_dir("fault-scan");
    let d = dir.to_str().unwrap();
    let args = one_cell_fault_scan("nan", "forces", d);
    let out = exompc(&args);
    assert!(out.status.success(), "{}", stderr(&out));
    let md = std::fs::read_to_string(dir.join("faults.md")).unwrap();
    assert!(md.contains("| nan | forces | 0.06 |"), "{md}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("faults.json")).unwrap()).unwrap();
    assert_eq!(json["cells"].as_array().map(Vec::len), Some(1));
    let png = std::fs::read(dir.join("faults.png")).unwrap();
    assert!(png.starts_with(b"\x89PNG\r\n\x1a\n") && png.len() > 1000);
    let svg = std::fs::read_to_string(dir.join("faults.svg")).unwrap();
    assert!(svg.contains("nan · forces") && svg.contains("force (N)"));
    let again = exompc(&args);
    assert_eq!(again.status.code(), Some(2), "{}", stderr(&again));
    assert!(stderr(&again).contains("--force"));
    assert_eq!(std::fs::read(dir.join("faults.png")).unwrap(), png);
}
