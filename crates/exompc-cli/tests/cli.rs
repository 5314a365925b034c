//! End-to-end tests of the `exompc` binary: `config` round trip and config rejection (exit 2).

use std::process::Output;

mod common;
use common::{exompc, scratch, stderr};

#[test]
fn config_prints_default_that_loads_back_identically() {
    let out = exompc(&["config"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.starts_with("# exompc scenario"),
        "comment header missing"
    );
    for table in [
        "[human.thigh]",
        "[robot.shank]",
        "[controller.sqp]",
        "[multistage]",
        "[monitors]",
    ] {
        assert!(text.contains(table), "missing {table}");
    }
    let parsed = exompc_cli::io::parse_scenario(&text).expect("printed config must load");
    assert_eq!(parsed, exompc::config::Experiment::default());

    let path = scratch("roundtrip.toml");
    std::fs::write(&path, &text).unwrap();
    let check = exompc(&["config", "--check", path.to_str().unwrap()]);
    assert!(check.status.success(), "{}", stderr(&check));
}

/// Writes `toml` to a file and runs `exompc simulate --config FILE`.
fn simulate_with(name: &str, toml: &str) -> Output {
    let path = scratch(name);
    std::fs::write(&path, toml).unwrap();
    let out = common::fresh_dir(&format!("{name}.out"));
    exompc(&[
        "simulate",
        "--config",
        path.to_str().unwrap(),
        "--duration",
        "1",
        "--out",
        out.to_str().unwrap(),
    ])
}

#[test]
fn bad_configs_exit_2_naming_the_field() {
    let cases: &[(&str, &str, &[&str])] = &[
        ("neg_mass.toml", "[robot.thigh]\nmass_kg = -1.0\n", &["robot.thigh.mass_kg", "-1"]),
        ("zero_dt.toml", "[timing]\ndt = 0.0\n", &["timing.dt"]),
        ("nan_gain.toml", "[controller.pd]\nkp = nan\n", &["controller.pd.kp", "NaN"]),
        ("inf_gain.toml", "[human]\nkd = inf\n", &["human.kd", "inf"]),
        ("empty_payloads.toml", "[multistage]\npayloads_kg = []\n", &["multistage.payloads_kg"]),
        ("nc_gt_np.toml", "[controller]\nnp = 3\nnc = 5\n", &["controller.nc"]),
        ("floor.toml", "[multistage]\nprobability_floor = 0.5\n", &["multistage.probability_floor"]),
        (
            "unknown_key.toml",
            "[robot.thigh]\nmasss_kg = 2.0\n",
            &["unknown key `masss_kg`", "[robot.thigh]", "did you mean `mass_kg`"],
        ),
        (
            "unknown_top.toml",
            "[controler]\nnp = 3\n",
            &["unknown key `controler`", "did you mean `controller`"],
        ),
        (
            "unknown_dotted.toml",
            "[multistage]\npayload_kg = [0.0]\n",
            &["`payload_kg`", "[multistage]", "did you mean `payloads_kg`"],
        ),
        (
            "unknown_fault_key.toml",
            "[[faults.events]]\nkind = \"spike\"\nchannel = \"f1\"\nstart_s = 1.0\nduration_s = 0.1\nmagnitud = 3.0\n",
            &["`magnitud`", "faults.events[0]", "did you mean `magnitude`"],
        ),
        ("bad_enum.toml", "[controller]\nkind = \"mpc\"\n", &["controller.kind", "msnmpc"]),
        ("bad_type.toml", "[timing]\ndt = \"fast\"\n", &["timing.dt", "expected a number"]),
        ("neg_int.toml", "[controller]\nnp = -3\n", &["controller.np"]),
        ("syntax.toml", "[human\nkp = 1\n", &["line 1"]),
    ];
    for (name, toml, needles) in cases {
        let out = simulate_with(name, toml);
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(2), "{name}: {err}");
        assert!(err.starts_with("error: "), "{name}: {err}");
        assert_eq!(
            err.trim_end().lines().count(),
            1,
            "{name}: one line expected: {err}"
        );
        for n in *needles {
            assert!(err.contains(n), "{name}: `{n}` not in: {err}");
        }
    }
}

#[test]
fn bad_config_is_rejected_by_every_scenario_command() {
    let path = scratch("neg_mass_all.toml");
    std::fs::write(&path, "[robot.shank]\nmass_kg = -2.0\n").unwrap();
    for cmd in ["simulate", "sweep", "soak", "bench"] {
        let out = exompc(&[cmd, "--config", path.to_str().unwrap()]);
        assert_eq!(out.status.code(), Some(2), "{cmd}");
        assert!(
            stderr(&out).contains("robot.shank.mass_kg"),
            "{cmd}: {}",
            stderr(&out)
        );
    }
}

#[test]
fn missing_config_file_names_the_path() {
    let out = exompc(&["simulate", "--config", "/nonexistent/dir/my.toml"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr(&out).contains("/nonexistent/dir/my.toml"),
        "{}",
        stderr(&out)
    );
}

#[test]
fn partial_config_is_accepted() {
    let out = simulate_with(
        "partial.toml",
        "[uncertainty]\npayload_kg = 2\n[human.thigh]\nmass_fraction = 0.11\n",
    );
    // A valid partial config runs.
    let err = stderr(&out);
    assert!(!err.contains("config file"), "{err}");
    assert_eq!(out.status.code(), Some(0), "{err}");
}

#[test]
fn bad_flags_exit_2() {
    let out = exompc(&["simulate", "--payload", "25"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr(&out).contains("uncertainty.payload_kg"),
        "{}",
        stderr(&out)
    );
    let out = exompc(&["simulate", "--dof", "3"]);
    assert_eq!(out.status.code(), Some(2));
    let out = exompc(&["no-such-command"]);
    assert_eq!(out.status.code(), Some(2));
}
