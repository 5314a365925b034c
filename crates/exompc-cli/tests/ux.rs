//! What a new user meets: verdict lines, monitor trips in the summary, interrupted and repeated
//! runs, config help, recorded gaits (issue 15).

use std::path::PathBuf;
use std::process::{Command, Output};

fn exompc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_exompc"))
        .args(args)
        .output()
        .expect("run exompc")
}

fn fresh_dir(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join("exompc-ux-tests")
        .join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.parent().unwrap()).unwrap();
    dir
}

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

    // 20 kg is far outside the scenarios: the monitors take over on many steps.
    let dir = fresh_dir("verdict_degraded");
    let out = exompc(&[
        "simulate",
        "--dof",
        "1",
        "--payload",
        "20",
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
