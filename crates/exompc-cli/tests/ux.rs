//! What a new user meets: verdict lines, monitor trips in the summary, interrupted and repeated
//! runs, config help, recorded gaits (issue 15).

mod common;

use common::{exompc, fresh_dir};

fn text(o: &[u8]) -> String {
    String::from_utf8_lossy(o).into_owned()
}

#[test]
fn simulate_prints_a_verdict_and_the_monitor_trips() {
    let ok_dir = fresh_dir("verdict_ok");
    let out = exompc(&["simulate", "--dof", "1", "--out", ok_dir.to_str().unwrap()]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert_eq!(stdout.lines().last(), Some("verdict: ok"), "{stdout}");

    // 20 kg is far outside the scenarios: with the paper's method (the robust default holds
    // it at 14 N) the monitors take over on many steps.
    let dir = fresh_dir("verdict_degraded");
    std::fs::create_dir_all(&dir).unwrap();
    let paper = dir.join("paper.toml");
    std::fs::write(&paper, "[controller]\nmethod = \"paper\"\n").unwrap();
    let out = exompc(&[
        "simulate",
        "--dof",
        "1",
        "--payload",
        "20",
        "--config",
        paper.to_str().unwrap(),
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    let last = stdout.lines().last().unwrap();
    assert!(last.starts_with("verdict: degraded ("), "{stdout}");
    assert!(last.contains("monitor trips"), "{last}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    let safety = &summary["safety"];
    let trips = safety["monitor_trips"].as_u64().unwrap();
    assert!(trips > 0, "{safety}");
    assert!(safety["monitor_steps"].as_u64().unwrap() > 0);
    let kinds = safety["monitors"].as_array().unwrap();
    assert!(!kinds.is_empty());
    let sum: u64 = kinds.iter().map(|k| k["trips"].as_u64().unwrap()).sum();
    assert_eq!(sum, trips, "per-kind trips add up: {safety}");
    for k in kinds {
        let name = k["monitor"].as_str().unwrap();
        assert!(stdout.contains(name), "{name} printed: {stdout}");
        let t = k["first_trip_s"].as_f64().unwrap();
        assert!(t > 0.0 && t < 30.0);
    }
}

#[test]
fn soak_prints_a_verdict() {
    let dir = fresh_dir("soak_verdict");
    let out = exompc(&["soak", "--hours", "0.005", "--out", dir.to_str().unwrap()]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    let last = stdout.lines().last().unwrap();
    assert!(
        last == "verdict: ok" || last.starts_with("verdict: degraded ("),
        "{stdout}"
    );
}

#[test]
fn conflicting_flags_are_rejected_and_sweep_takes_a_duration() {
    let out = exompc(&[
        "simulate",
        "--formulation",
        "coupled",
        "--controller",
        "nmpc",
    ]);
    assert_eq!(out.status.code(), Some(2));
    let err = text(&out.stderr);
    assert!(
        err.contains("--formulation coupled") && err.contains("--controller nmpc"),
        "{err}"
    );
    let out = exompc(&[
        "sweep",
        "--formulation",
        "coupled",
        "--controllers",
        "nmpc,pd",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out.stderr).contains("--formulation coupled"));

    let out = exompc(&["sweep", "--duration", "-1"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        text(&out.stderr).contains("--duration"),
        "{}",
        text(&out.stderr)
    );
    let dir = fresh_dir("sweep_duration");
    let out = exompc(&[
        "sweep",
        "--dof",
        "1",
        "--payloads",
        "1",
        "--controllers",
        "pd",
        "--duration",
        "0.5",
        "--quiet",
        "--json",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let sweep: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let d = sweep["rows"][0]["duration_s"].as_f64().unwrap();
    assert!((d - 0.5).abs() < 1e-9, "{d}");
}

/// Entries of `dir` (names), sorted.
fn entries(dir: &std::path::Path) -> Vec<String> {
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

#[test]
fn sweep_refuses_a_folder_with_earlier_results_unless_forced() {
    let dir = fresh_dir("sweep_force");
    let args = |payloads: &'static str, force: bool| {
        let mut v = vec![
            "sweep",
            "--dof",
            "1",
            "--controllers",
            "pd",
            "--duration",
            "0.2",
            "--quiet",
            "--payloads",
            payloads,
            "--out",
            dir.to_str().unwrap(),
        ];
        if force {
            v.push("--force");
        }
        v
    };
    let out = exompc(&args("0,1", false));
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(dir.join("pd_1kg/summary.json").is_file());
    let again = exompc(&args("0", false));
    assert_eq!(again.status.code(), Some(2));
    assert!(
        text(&again.stderr).contains("--force"),
        "{}",
        text(&again.stderr)
    );
    std::fs::write(dir.join("notes.txt"), "mine").unwrap();
    let forced = exompc(&args("0", true));
    assert!(forced.status.success(), "{}", text(&forced.stderr));
    assert_eq!(
        entries(&dir),
        ["notes.txt", "pd_0kg", "sweep.json", "table2.md"],
        "old run folders gone, the user's own file kept"
    );
}

#[test]
fn a_key_in_the_wrong_table_is_pointed_to_its_table() {
    let dir = fresh_dir("wrong_table");
    std::fs::create_dir_all(&dir).unwrap();
    for (toml, want) in [
        (
            "payload_kg = 2.0\n",
            "`payload_kg` belongs in [uncertainty]",
        ),
        (
            "[robot]\nmass_kg = 2.0\n",
            "`mass_kg` belongs in [robot.shank] or [robot.thigh]",
        ),
    ] {
        let path = dir.join("c.toml");
        std::fs::write(&path, toml).unwrap();
        let out = exompc(&["config", "--check", path.to_str().unwrap()]);
        assert_eq!(out.status.code(), Some(2));
        let err = text(&out.stderr);
        assert!(err.contains(want), "{toml}: {err}");
    }
}

#[test]
fn refused_starts_leave_no_folder_and_every_writer_refuses_to_overwrite() {
    // A start refused after the folder was created (a bad grid cell) leaves no empty folder.
    let dir = fresh_dir("refused_envelope").join("deep/er");
    let out = exompc(&[
        "envelope",
        "--set",
        "robot.payload_position_m=0.5",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
    assert!(!dir.parent().unwrap().exists(), "{}", text(&out.stderr));

    // envelope refuses an earlier scan's folder unless --force, naming what it would replace.
    let dir = fresh_dir("envelope_force");
    let args = |force: bool| {
        let mut v = vec![
            "envelope",
            "--set",
            "timing.duration_1dof_s=0.3",
            "--dof",
            "1",
            "--payloads",
            "0",
            "--controllers",
            "pd",
            "--quiet",
            "--out",
            dir.to_str().unwrap(),
        ];
        if force {
            v.push("--force");
        }
        v
    };
    let first = exompc(&args(false));
    assert!(first.status.success(), "{}", text(&first.stderr));
    let again = exompc(&args(false));
    assert_eq!(again.status.code(), Some(2));
    let err = text(&again.stderr);
    assert!(
        err.contains("envelope.json") && err.contains("--force"),
        "{err}"
    );
    let forced = exompc(&args(true));
    assert!(forced.status.success(), "{}", text(&forced.stderr));

    // gait export likewise, and creates the folders of its output path.
    let file = fresh_dir("gait_force").join("sub/walk.csv");
    let f = file.to_str().unwrap();
    let export = |force: bool| {
        let mut v = vec!["gait", "export", "--duration", "1", "--out", f];
        if force {
            v.push("--force");
        }
        exompc(&v)
    };
    assert!(export(false).status.success());
    let again = export(false);
    assert_eq!(again.status.code(), Some(2));
    assert!(
        text(&again.stderr).contains("--force"),
        "{}",
        text(&again.stderr)
    );
    assert!(export(true).status.success());
}
