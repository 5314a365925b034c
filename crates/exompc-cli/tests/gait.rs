//! Recorded gaits from the command line: the example recording replays the parametric run,
//! `gait export` reproduces it, and every bad file gets an error naming file, line and column.

mod common;

use common::{exompc, fresh_dir, scratch, stderr};
use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Runs `simulate` with `args` into a fresh folder; returns (summary JSON, RMS tracking error
/// |q_human − q_robot| per joint from the trace, rad).
fn simulate(name: &str, args: &[&str]) -> (serde_json::Value, Vec<f64>) {
    let out = fresh_dir(name);
    let mut all = vec!["simulate", "--out", out.to_str().unwrap(), "--json"];
    all.extend_from_slice(args);
    let o = exompc(&all);
    assert!(o.status.success(), "{args:?}: {}", stderr(&o));
    let text = String::from_utf8(o.stdout).unwrap();
    let summary: serde_json::Value = serde_json::from_str(text.lines().last().unwrap()).unwrap();
    let trace = std::fs::read_to_string(out.join("trace.csv")).unwrap();
    let mut lines = trace.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |n: &str| header.iter().position(|h| *h == n).unwrap();
    let pairs = [
        (col("q_human_hip"), col("q_robot_hip")),
        (col("q_human_knee"), col("q_robot_knee")),
    ];
    let mut sum = [0.0; 2];
    let mut n = 0.0;
    for l in lines {
        let v: Vec<&str> = l.split(',').collect();
        for (j, (h, r)) in pairs.iter().enumerate() {
            let d: f64 = v[*h].parse::<f64>().unwrap() - v[*r].parse::<f64>().unwrap();
            sum[j] += d * d;
        }
        n += 1.0;
    }
    (summary, sum.iter().map(|s| (s / n).sqrt()).collect())
}

fn close(what: &str, a: f64, b: f64) {
    assert!(
        (a - b).abs() <= 0.01 * b.abs(),
        "{what}: recorded {a} vs parametric {b}"
    );
}

#[test]
fn the_example_recording_replays_the_parametric_run_within_1_percent() {
    let config = repo().join("examples/recorded_gait.toml");
    let csv = repo().join("examples/gaits/parametric_2dof.csv");
    for controller in ["msnmpc", "nmpc"] {
        let base = ["--controller", controller, "--payload", "2"];
        let (p, p_track) = simulate(&format!("param-{controller}"), &base);
        // MS-NMPC through the example config file, NMPC through --gait.
        let mut args = base.to_vec();
        if controller == "msnmpc" {
            args.extend(["--config", config.to_str().unwrap()]);
        } else {
            args.extend(["--gait", csv.to_str().unwrap()]);
        }
        let (r, r_track) = simulate(&format!("rec-{controller}"), &args);
        for strap in ["thigh", "shank"] {
            close(
                &format!("{controller} rms force {strap}"),
                r["rms_force_n"][strap].as_f64().unwrap(),
                p["rms_force_n"][strap].as_f64().unwrap(),
            );
        }
        for joint in ["hip", "knee"] {
            close(
                &format!("{controller} max tracking error {joint}"),
                r["delta_max_deg"][joint].as_f64().unwrap(),
                p["delta_max_deg"][joint].as_f64().unwrap(),
            );
        }
        for j in 0..2 {
            close(
                &format!("{controller} rms tracking {j}"),
                r_track[j],
                p_track[j],
            );
        }
        assert_eq!(r["steps"], p["steps"]);
    }
}

#[test]
fn gait_export_reproduces_the_example_files() {
    for (dof, name) in [("2", "parametric_2dof.csv"), ("1", "parametric_1dof.csv")] {
        let out = scratch(&format!("export-{name}"));
        // gait export refuses to overwrite an earlier file (without --force).
        let _ = std::fs::remove_file(&out);
        let o = exompc(&[
            "gait",
            "export",
            "--dof",
            dof,
            "--rate",
            "100",
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let ours = std::fs::read_to_string(&out).unwrap();
        let committed = std::fs::read_to_string(repo().join("examples/gaits").join(name)).unwrap();
        assert!(
            ours == committed,
            "{name} differs from `exompc gait export --dof {dof}`"
        );
    }
}

/// `simulate` of a short run with the gait file `text` (written to `name`) and `extra` flags;
/// returns stderr, asserting failure.
fn fails_with(name: &str, text: &str, extra: &[&str], expected: &[&str]) {
    let file = scratch(name);
    std::fs::write(&file, text).unwrap();
    let out = fresh_dir(&format!("out-{name}"));
    let mut args = vec![
        "simulate",
        "--gait",
        file.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    if !extra.contains(&"--duration") {
        args.extend(["--duration", "0.5"]);
    }
    args.extend_from_slice(extra);
    let o = exompc(&args);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{name}: {err}");
    for e in expected {
        assert!(err.contains(e), "{name}: `{e}` not in: {err}");
    }
}

/// A 1 s recording at 100 Hz of a slow motion, `f(t)` per sample.
fn one_second(header: &str, f: impl Fn(f64) -> String) -> String {
    let mut s = format!("{header}\n");
    for k in 0..=100 {
        let t = k as f64 / 100.0;
        s.push_str(&format!("{t},{}\n", f(t)));
    }
    s
}

/// `text` with its line `line` (from 1) replaced by `new`.
fn with_line(text: &str, line: usize, new: &str) -> String {
    let mut lines: Vec<&str> = text.lines().collect();
    lines[line - 1] = new;
    lines.join("\n") + "\n"
}

#[test]
fn bad_gait_files_name_file_line_and_column() {
    let good = |t: f64| format!("{},{}", 0.1 * t, -0.2 * t);
    fails_with(
        "unknown.csv",
        &one_second("t_s,hip_rad,ankle_rad", good),
        &[],
        &[
            "unknown.csv",
            "line 1, column 3",
            "unknown column `ankle_rad`",
            "knee_rad",
        ],
    );
    fails_with(
        "noknee.csv",
        &one_second("t_s,hip_rad", |t| format!("{t}")),
        &[],
        &["noknee.csv", "no knee angle column"],
    );
    let base = one_second("t_s,hip_rad,knee_rad", good);
    fails_with(
        "nan.csv",
        &with_line(&base, 7, "0.05,0.005,abc"),
        &[],
        &[
            "nan.csv, line 7, column 3 (knee_rad)",
            "`abc` is not a number",
        ],
    );
    fails_with(
        "time.csv",
        &with_line(&base, 5, "0.01,0,0"),
        &[],
        &[
            "time.csv, line 5, column 1 (t_s)",
            "not after the previous sample's 0.02 s",
        ],
    );
    fails_with(
        "inf.csv",
        &with_line(&base, 12, "0.1,inf,0"),
        &[],
        &[
            "inf.csv, line 12, column 2 (hip_rad)",
            "not a finite number",
        ],
    );
    fails_with(
        "few.csv",
        "t_s,knee_rad\n0,0\n0.1,0.1\n0.2,0.1\n",
        &["--dof", "1"],
        &["few.csv", "3 samples", "at least 4"],
    );
    fails_with(
        "degrees.csv",
        &one_second("t_s,hip_rad,knee_rad", |t| format!("{},{}", 0.5, -40.0 - t)),
        &[],
        &[
            "degrees.csv, line 2, column 3 (knee_rad)",
            "beyond ±2π",
            "name it knee_deg",
        ],
    );
    fails_with(
        "short.csv",
        &one_second("t_s,hip_rad,knee_rad", good),
        &["--duration", "3"],
        &[
            "trajectory.file",
            "recording is 1 s, run asks 3 s",
            "timing.duration_2dof_s",
        ],
    );
    fails_with(
        "kneeonly.csv",
        &one_second("t_s,knee_rad", |t| format!("{}", -0.2 * t)),
        &[],
        &["trajectory.file", "hip column"],
    );
}

#[test]
fn degrees_loops_and_config_relative_paths_work() {
    // A 1 s loop (last sample = first) replays for 3 s; the same motion in degrees runs too.
    let rad = one_second("t_s,hip_rad,knee_rad", |t| {
        let p = (2.0 * std::f64::consts::PI * t).sin();
        format!("{},{}", 0.1 + 0.2 * p, -0.3 - 0.2 * p)
    });
    let deg = one_second("time_s,knee_deg,hip_deg", |t| {
        let p = (2.0 * std::f64::consts::PI * t).sin();
        format!(
            "{},{}",
            (-0.3 - 0.2 * p).to_degrees(),
            (0.1 + 0.2 * p).to_degrees()
        )
    });
    let dir = fresh_dir("gait-config");
    std::fs::create_dir_all(dir.join("data")).unwrap();
    std::fs::write(dir.join("data/loop.csv"), &rad).unwrap();
    std::fs::write(dir.join("data/loop_deg.csv"), &deg).unwrap();
    std::fs::write(
        dir.join("loop.toml"),
        "[trajectory]\nkind = \"recorded\"\nfile = \"data/loop.csv\"\n",
    )
    .unwrap();
    let cfg = dir.join("loop.toml");
    let (a, _) = simulate(
        "loop-rad",
        &[
            "--config",
            cfg.to_str().unwrap(),
            "--duration",
            "3",
            "--controller",
            "nmpc",
        ],
    );
    let degf = dir.join("data/loop_deg.csv");
    let (b, _) = simulate(
        "loop-deg",
        &[
            "--gait",
            degf.to_str().unwrap(),
            "--duration",
            "3",
            "--controller",
            "nmpc",
        ],
    );
    assert_eq!(a["steps"], 300);
    for strap in ["thigh", "shank"] {
        let (x, y) = (
            a["rms_force_n"][strap].as_f64().unwrap(),
            b["rms_force_n"][strap].as_f64().unwrap(),
        );
        assert!(x > 0.0 && (x - y).abs() <= 1e-6 * x, "{strap}: {x} vs {y}");
    }
    // `file` without kind = "recorded", and kind = "recorded" without file.
    for (toml, expected) in [
        (
            "[trajectory]\nfile = \"data/loop.csv\"\n",
            "trajectory.kind",
        ),
        ("[trajectory]\nkind = \"recorded\"\n", "trajectory.file"),
    ] {
        let f = dir.join("bad.toml");
        std::fs::write(&f, toml).unwrap();
        let o = exompc(&["config", "--check", f.to_str().unwrap()]);
        assert_eq!(o.status.code(), Some(2));
        assert!(stderr(&o).contains(expected), "{}", stderr(&o));
    }
    let o = exompc(&["config", "--check", cfg.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn the_trajectory_table_rejects_unknown_keys_through_serde_alone() {
    // Without the CLI's key check: the library type itself denies unknown keys (the flattened
    // parametric keys included) and reads the flat table.
    use exompc::config::{Experiment, TrajectoryKind};
    let bad = toml::from_str::<Experiment>("[trajectory]\nhip_amplitud = 0.3\n");
    assert!(bad.unwrap_err().to_string().contains("hip_amplitud"));
    let s: Experiment = toml::from_str(
        "[trajectory]\nkind = \"sine\"\nhip_amplitude = 0.25\none_dof_amplitude = 0.5\n",
    )
    .unwrap();
    assert_eq!(s.trajectory.kind, TrajectoryKind::Parametric);
    assert_eq!(
        (
            s.trajectory.swing.hip_amplitude,
            s.trajectory.knee.amplitude
        ),
        (0.25, 0.5)
    );
    assert_eq!(s.trajectory.swing.knee_amplitude, 1.0);
    // Serialised flat, as the table is written.
    let text = toml::to_string(&s).unwrap();
    assert!(text.contains("hip_amplitude = 0.25") && text.contains("one_dof_amplitude = 0.5"));
    assert_eq!(toml::from_str::<Experiment>(&text).unwrap(), s);
}
