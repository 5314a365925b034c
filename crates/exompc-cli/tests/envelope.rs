//! The operating envelope as a test (issue 10): the standard grid's acceptance for the default
//! controller (every cell passes), the scan machinery on cells that pass
//! and on one that fails today, and `exompc envelope` end to end.

use exompc::config::Experiment;
use exompc::sim::{RunClass, StabilityCriteria};
use exompc_cli::envelope::{markdown, scan, scan_until, without_monitors, Envelope, Grid};
use exompc_cli::error::CliError;
use std::process::Command;
use std::sync::atomic::{AtomicUsize, Ordering};

fn run(grid: &Grid) -> Envelope {
    run_on(&Experiment::default(), grid)
}

fn run_on(base: &Experiment, grid: &Grid) -> Envelope {
    scan(base, grid, &StabilityCriteria::default(), &|| {}).unwrap()
}

fn describe_failures(env: &Envelope) -> String {
    env.failing()
        .iter()
        .map(|v| format!("{}, {} kg: {}", v.name, v.payload_kg, v.failures()))
        .collect::<Vec<_>>()
        .join("\n")
}

/// Issue 10 "Done when": in every cell of the standard envelope (envelopes/standard.toml,
/// 18 cells × 0-3 kg, ~7 s in release) the default MS-NMPC, with the safety monitors as
/// deployed, is stable, RMS < 20 N (unless torque-limited), within the limits, no worse than
/// the NMPC, and trips no monitor — unless the cell's gait needs more torque than the actuator
/// has on more than 5 % of the instants and the NMPC tripped too (the straps must then carry
/// the shortfall and the strap-force monitor must trip whatever the controller does; the
/// issue's rule for torque-limited cells, stability and "no worse than NMPC", still holds).
///
/// One cell passes by that waiver: gait 1.3 Hz, 3 kg, whose gait needs up to 67 N·m at the hip
/// of a ±30 N·m actuator (beyond it on 40 % of the instants). MS-NMPC there 39.8 / 11.9 N,
/// saturating, growth 1.14, 35 trips; the NMPC 40.2 / 13.4 N, 40 trips. The history of the
/// failing count: the disturbance bank and the torque detector of the fifth pass took it from
/// 14 to 9, the sixth pass's weight smoothing and inertia gate to 6, the seventh pass's strap
/// observer to 3, the eighth pass's gait-following oscillation cut-off and the weight
/// low-pass's start to 1, the ninth pass's strap-space velocity residual (that cell 37.7 /
/// 20.8 N growing → 39.8 / 11.9 N) and the demand waiver to 0; docs/ROBUSTNESS.md §4. The
/// paper-method default fails 22 of 72.
#[test]
fn standard_envelope_meets_the_acceptance() {
    let env = run(&Grid::standard());
    assert_eq!(env.verdicts.len(), 72);
    assert!(
        env.failing().is_empty(),
        "failing cells:\n{}",
        describe_failures(&env)
    );
    // The waiver is used by the overloaded cell alone, and that cell's gait needs more than
    // twice the actuator's torque at the hip (the robot with its payload moving exactly with
    // the human's desired motion), on ~40 % of the instants; the default cell's gait stays
    // within the limit at every payload.
    let waived: Vec<(String, f64)> = env
        .verdicts
        .iter()
        .filter(|v| v.verdict.as_ref().unwrap().trips_waived)
        .map(|v| (v.name.clone(), v.payload_kg))
        .collect();
    assert_eq!(waived, vec![("gait 1.3 Hz".to_string(), 3.0)]);
    let cell = |name: &str| env.grid.cells.iter().position(|c| c.name == name).unwrap();
    let d = env.demand(cell("gait 1.3 Hz"), 3.0).unwrap();
    assert!(d.exceeds_limit(), "{d:?}");
    assert!(d.peak_nm[0] > 2.0 * d.torque_max_nm, "{d:?}");
    assert!((0.3..0.5).contains(&d.beyond_limit_fraction), "{d:?}");
    for p in [0.0, 1.0, 2.0, 3.0] {
        let d = env.demand(cell("default"), p).unwrap();
        assert!(!d.exceeds_limit(), "{p} kg: {d:?}");
        assert!(d.peak_nm.iter().all(|&t| t > 0.0 && t < d.torque_max_nm));
    }
    assert_eq!(env.demands.len(), 72);
    let md = markdown(&env);
    assert!(md.contains("72 of 72 cells pass"), "{md}");
    assert!(
        md.contains("Passing with their monitor trips waived"),
        "{md}"
    );
    assert!(md.contains("gait 1.3 Hz at 3 kg"), "{md}");
}

/// The machinery on a reduced grid: cells that pass today pass, and a cell that limit-cycles
/// with the paper's bare method (filter window 9 at 1 kg, monitors out of reach) is caught as
/// unstable and worse than the NMPC. (With the monitors on, the fallback response calms the
/// limit cycle so well that the cell is no longer worse than the NMPC — it fails on the
/// instability and the trips instead.)
#[test]
fn envelope_scan_judges_cells() {
    let mut g = Grid::standard();
    let keep = ["default", "filter window 1", "straps x0.5", "gait 0.6 Hz"];
    g.cells.retain(|c| keep.contains(&c.name.as_str()));
    g.payloads_kg = vec![0.0, 2.0];
    let env = run(&g);
    assert_eq!(env.runs.len(), 4 * 2 * 2);
    assert_eq!(env.verdicts.len(), 8);
    assert!(env.failing().is_empty(), "{}", describe_failures(&env));
    for r in &env.runs {
        let st = r.stability.as_ref().unwrap();
        assert_eq!(st.class, RunClass::Stable, "{r:?}");
        assert_eq!(r.summary.as_ref().unwrap().limit_violations, 0);
        assert_eq!(r.monitor_trips, 0);
    }

    let bad = Grid::product(
        &[
            "uncertainty.filter_window=9".into(),
            "controller.method=paper".into(),
        ],
        2,
        vec![1.0],
        vec!["nmpc".into(), "msnmpc".into()],
    )
    .unwrap();
    let env = run_on(&without_monitors(&Experiment::default()), &bad);
    let v = env.verdicts[0].verdict.clone().unwrap();
    assert!(!v.pass && !v.stable && !v.no_worse_than_nmpc, "{v:?}");
    assert_eq!(
        env.run(0, 1.0, "nmpc")
            .unwrap()
            .stability
            .as_ref()
            .unwrap()
            .class,
        RunClass::Stable
    );
}

/// `scan_until` stops when asked: before the runs (an `Interrupted` error), or during them
/// (every run ends between two control steps with an error entry, none completes).
#[test]
fn scan_until_stops_when_asked() {
    let mut s = Experiment::default();
    s.timing.duration_2dof_s = 2.0;
    let mut g = Grid::standard();
    g.cells.retain(|c| c.name == "default");
    g.payloads_kg = vec![0.0, 1.0];
    let crit = StabilityCriteria::default();
    let before = scan_until(&s, &g, &crit, &|| {}, &|| true);
    assert!(
        matches!(before, Err(CliError::Interrupted(_))),
        "{before:?}"
    );
    // Polls 1-2 are the two payloads' gait demands; from poll 50 on the runs are asked to stop.
    let polls = AtomicUsize::new(0);
    let stop = || polls.fetch_add(1, Ordering::SeqCst) >= 50;
    let env = scan_until(&s, &g, &crit, &|| {}, &stop).unwrap();
    assert_eq!(env.runs.len(), 4);
    assert!(env
        .runs
        .iter()
        .all(|r| r.summary.is_none() && r.error.is_some()));
    // 200 control steps per run: without the stop each run would poll 200 times.
    assert!(polls.load(Ordering::SeqCst) <= 50 + 4 * 2, "{polls:?}");
    let full = scan_until(&s, &g, &crit, &|| {}, &|| false).unwrap();
    let plain = scan(&s, &g, &crit, &|| {}).unwrap();
    let rms = |e: &Envelope| -> Vec<_> {
        e.runs
            .iter()
            .map(|r| r.summary.as_ref().map(|x| x.rms_force_n))
            .collect()
    };
    assert!(full.runs.iter().all(|r| r.error.is_none()));
    assert_eq!(rms(&full), rms(&plain));
}

#[test]
fn envelope_command_writes_json_markdown_and_heat_map() {
    let dir = std::env::temp_dir().join(format!("exompc-envelope-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let cfg = dir.join("short.toml");
    std::fs::create_dir_all(&dir).unwrap();
    // The paper's method, which fails the filter-window-9 cell.
    std::fs::write(
        &cfg,
        "[timing]\nduration_2dof_s = 5.0\n[controller]\nmethod = \"paper\"\n",
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_exompc"))
        .args(["envelope", "--quiet", "--config"])
        .arg(&cfg)
        .args([
            "--set",
            "uncertainty.filter_window=1,9",
            "--payloads",
            "1",
            "--check",
            "--out",
        ])
        .arg(&dir)
        .output()
        .unwrap();
    // filter window 9 fails the acceptance: --check exits 1 after writing everything.
    assert_eq!(
        out.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for f in [
        "envelope.json",
        "envelope.md",
        "envelope.png",
        "envelope.svg",
    ] {
        assert!(dir.join(f).is_file(), "{f}");
    }
    let env: Envelope =
        serde_json::from_str(&std::fs::read_to_string(dir.join("envelope.json")).unwrap()).unwrap();
    assert_eq!(env.grid.cells.len(), 2);
    assert_eq!(env.runs.len(), 4);
    assert!(env.verdicts[0].pass(), "{:?}", env.verdicts[0]);
    assert!(!env.verdicts[1].pass());
    let md = std::fs::read_to_string(dir.join("envelope.md")).unwrap();
    assert!(md.contains("uncertainty.filter_window=9") && md.contains("1 of 2 cells pass"));

    // A bad key names the field; exit 2.
    let out = Command::new(env!("CARGO_BIN_EXE_exompc"))
        .args([
            "envelope",
            "--quiet",
            "--set",
            "robot.payload_pos=0.1",
            "--out",
        ])
        .arg(&dir)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("payload_position_m"));
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 33 item 6: recorded gaits as a grid axis. The shipped grid over three recorded walking
/// speeds (envelopes/recorded_gaits.toml, gait files relative to it) runs every cell on its
/// own recording: the gait's torque demand grows with the speed; on the command line the same
/// axis is `--set trajectory.file=a.csv,b.csv` (kind "recorded" implied).
#[test]
fn recorded_gaits_are_a_grid_axis() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let path = root.join("envelopes/recorded_gaits.toml");
    let mut grid = Grid::parse(&std::fs::read_to_string(&path).unwrap(), "grid").unwrap();
    grid.base = path.parent().unwrap().to_path_buf();
    grid.payloads_kg = vec![1.0];
    grid.controllers = vec!["msnmpc".into()];
    let base = Experiment::default();
    let mut peaks = Vec::new();
    for cell in &grid.cells {
        let s = grid.cell_scenario(&base, cell).unwrap();
        assert!(s.trajectory.recording.is_some(), "{}", cell.name);
    }
    let env = run_on(&base, &grid);
    for (i, cell) in grid.cells.iter().enumerate() {
        let r = env.run(i, 1.0, "msnmpc").unwrap();
        assert_eq!(r.class_name(), "stable", "{}: {:?}", cell.name, r.error);
        peaks.push(env.demand(i, 1.0).unwrap().peak_nm[0]);
    }
    assert!(peaks.windows(2).all(|w| w[0] < w[1]), "{peaks:?}");

    // The same axis from `--set`, files relative to the working directory.
    let gaits = root.join("examples/gaits");
    let files = ["walk_0.6hz.csv", "walk_1.1hz.csv"]
        .map(|f| gaits.join(f).to_string_lossy().into_owned())
        .join(",");
    let g = Grid::product(&[format!("trajectory.file={files}")], 2, vec![0.0], vec![]).unwrap();
    assert_eq!(g.cells.len(), 2);
    for cell in &g.cells {
        let s = Grid::scenario(&base, cell).unwrap();
        assert_eq!(s.trajectory.kind, exompc::config::TrajectoryKind::Recorded);
    }
}
