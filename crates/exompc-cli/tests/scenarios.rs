//! Named multi-stage scenarios from a config file alone (`[[multistage.scenarios]]`): the
//! example files run through `exompc simulate`, their names reach the trace, the summary and
//! the figures, indistinguishable scenarios are warned about on stderr, and bad entries exit 2
//! naming the field.

use std::path::{Path, PathBuf};
use std::process::Output;

mod common;
use common::{exompc, fresh_dir, scratch, stderr};

fn example(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../examples")
        .join(name)
}

fn simulate(config: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "simulate",
        "--config",
        config.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    exompc(&args)
}

fn read(p: &Path) -> String {
    std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

fn summary(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&read(&dir.join("summary.json"))).unwrap()
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Header and last row of `dir/trace.csv`.
fn trace(dir: &Path) -> (Vec<String>, Vec<String>) {
    let text = read(&dir.join("trace.csv"));
    let mut lines = text.lines();
    let head = lines.next().unwrap().split(',').map(String::from).collect();
    let last = lines.last().unwrap().split(',').map(String::from).collect();
    (head, last)
}

#[test]
fn strap_stiffness_scenarios_run_from_the_config_file_with_a_warning() {
    let out = fresh_dir("straps");
    let o = simulate(
        &example("scenarios_strap_stiffness.toml"),
        &out,
        &["--duration", "2", "--plot"],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let err = stderr(&o);
    // Three pairs, each warned once, naming the differing keys.
    assert_eq!(err.matches("warning: ").count(), 3, "{err}");
    assert!(
        err.contains("\"loose straps\" and \"tight straps\"")
            && err.contains("straps.stiffness, straps.damping")
            && err.contains("cannot tell them apart"),
        "{err}"
    );
    let names = ["loose straps", "nominal straps", "tight straps"];
    let (head, last) = trace(&out);
    for n in names {
        assert!(head.contains(&format!("mu_{n}")), "{head:?}");
        assert!(head.contains(&format!("dist_{n}_knee")), "{head:?}");
    }
    // Same EKF models: equal probabilities to the end.
    let mu: Vec<f64> = names
        .iter()
        .map(|n| {
            let i = head.iter().position(|c| *c == format!("mu_{n}")).unwrap();
            last[i].parse().unwrap()
        })
        .collect();
    assert!(mu.iter().all(|&p| p == mu[0]), "{mu:?}");
    let s = summary(&out);
    assert_eq!(s["scenarios"], serde_json::json!(names));
    assert!(stdout(&o).contains("loose straps 33.33%"), "{}", stdout(&o));
    let svg = read(&out.join("interaction.svg"));
    for n in names {
        assert!(svg.contains(n), "legend {n} missing from interaction.svg");
    }
    assert!(!svg.contains("μ1"));
}

#[test]
fn shank_mass_scenarios_identify_the_plant_from_the_config_file() {
    let out = fresh_dir("shank");
    let o = simulate(
        &example("scenarios_shank_mass.toml"),
        &out,
        &["--duration", "8", "--plot"],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stderr(&o).contains("warning"), "{}", stderr(&o));
    let names = ["nominal shank", "heavy shank", "heavier shank"];
    let s = summary(&out);
    assert_eq!(s["scenarios"], serde_json::json!(names));
    let mean: Vec<f64> = serde_json::from_value(s["mean_probability"].clone()).unwrap();
    assert!(mean[1] > 0.8, "{mean:?}");
    let (head, last) = trace(&out);
    let mu = |n: &str| -> f64 {
        let i = head.iter().position(|c| *c == format!("mu_{n}")).unwrap();
        last[i].parse().unwrap()
    };
    assert!(
        mu("heavy shank") > mu("nominal shank") && mu("heavy shank") > mu("heavier shank"),
        "{last:?}"
    );
    let svg = read(&out.join("interaction.svg"));
    for n in names {
        assert!(svg.contains(n), "legend {n} missing from interaction.svg");
    }
    // The 1-DOF layout reads the same file.
    let out1 = fresh_dir("shank1");
    let o = simulate(
        &example("scenarios_shank_mass.toml"),
        &out1,
        &["--dof", "1", "--duration", "3"],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(trace(&out1)
        .0
        .contains(&"dist_heavy shank_knee".to_string()));
}

#[test]
fn payload_shorthand_keeps_its_columns_and_gains_names() {
    let out = fresh_dir("payloads");
    let o = exompc(&[
        "simulate",
        "--duration",
        "1",
        "--out",
        out.to_str().unwrap(),
        "--plot",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stderr(&o).contains("warning"), "{}", stderr(&o));
    let (head, _) = trace(&out);
    for c in ["mu_1", "mu_2", "mu_3", "dist_1_hip", "dist_3_knee"] {
        assert!(head.contains(&c.to_string()), "{c} missing: {head:?}");
    }
    assert_eq!(
        summary(&out)["scenarios"],
        serde_json::json!(["0 kg", "1 kg", "2 kg"])
    );
    assert!(
        stdout(&o).contains("mean probability  0 kg "),
        "{}",
        stdout(&o)
    );
    let svg = read(&out.join("interaction.svg"));
    assert!(svg.contains("1 kg") && !svg.contains("μ1"));
}

#[test]
fn bad_scenario_entries_exit_2_naming_the_field() {
    let entries = "[[multistage.scenarios]]\nname = \"a\"\n\n[[multistage.scenarios]]\nname = \"b\"\n\n[[multistage.scenarios]]\nname = \"c\"\n";
    let cases: &[(&str, String, &[&str])] = &[
        (
            "neg_stiffness.toml",
            format!("{entries}straps.stiffness = -5.0\n"),
            &["multistage.scenarios[2].straps.stiffness", "-5", "> 0"],
        ),
        (
            "shank_mass.toml",
            format!("{entries}robot.shank.mass_kg = 0.0\n"),
            &["multistage.scenarios[2].robot.shank.mass_kg"],
        ),
        (
            "duplicate.toml",
            format!("{entries}\n[[multistage.scenarios]]\nname = \"a\"\n"),
            &["multistage.scenarios[3].name", "multistage.scenarios[0]"],
        ),
        (
            "empty_name.toml",
            "[[multistage.scenarios]]\nname = \"\"\n".into(),
            &["multistage.scenarios[0].name"],
        ),
        (
            "payload.toml",
            format!("{entries}payload_kg = 30.0\n"),
            &["multistage.scenarios[2].payload_kg", "[0, 20]"],
        ),
        (
            "both.toml",
            format!("[multistage]\npayloads_kg = [0.0, 1.0]\n\n{entries}"),
            &["multistage.payloads_kg", "[[multistage.scenarios]]"],
        ),
        (
            "typo.toml",
            format!("{entries}straps.stifness = 1.0\n"),
            &["`stifness`", "did you mean `stiffness`"],
        ),
    ];
    for (name, toml, needles) in cases {
        let path = scratch(name);
        std::fs::write(&path, toml).unwrap();
        let o = simulate(
            &path,
            &scratch(&format!("{name}.out")),
            &["--duration", "1"],
        );
        assert_eq!(o.status.code(), Some(2), "{name}: {}", stderr(&o));
        let err = stderr(&o);
        for n in *needles {
            assert!(err.contains(n), "{name}: `{n}` not in: {err}");
        }
    }
}

#[test]
fn config_round_trips_named_scenarios() {
    let path = example("scenarios_shank_mass.toml");
    let check = exompc(&["config", "--check", path.to_str().unwrap()]);
    assert!(check.status.success(), "{}", stderr(&check));
    let s = exompc_cli::io::parse_scenario(&read(&path)).unwrap();
    assert_eq!(s.multistage.scenarios.len(), 3);
    let text = toml::to_string(&s).unwrap();
    assert_eq!(exompc_cli::io::parse_scenario(&text).unwrap(), s);
}
