//! Config help (issue 15): cross-field errors name the key the user set and the key it
//! conflicts with; `exompc config` comments every key; `exompc config --explain KEY`.

mod common;
use common::{exompc, scratch, stderr};

/// Runs `exompc config --check FILE` on `toml` (or `simulate` with `extra` flags).
fn check(name: &str, toml: &str, extra: &[&str]) -> std::process::Output {
    let path = scratch(name);
    std::fs::write(&path, toml).unwrap();
    if extra.is_empty() {
        exompc(&["config", "--check", path.to_str().unwrap()])
    } else {
        let out = scratch(&format!("{name}.out"));
        let mut args = vec![
            "simulate",
            "--config",
            path.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        exompc(&args)
    }
}

#[test]
fn cross_field_errors_name_the_key_set_and_the_key_it_conflicts_with() {
    let cases: &[(&str, &str, &[&str], &[&str])] = &[
        // The case: the user shortened the link, the default strap no longer fits.
        (
            "thigh.toml",
            "[robot.thigh]\nlength_m = 0.2\n",
            &[],
            &[
                "robot.thigh.length_m = 0.2 (your setting) and straps.ls1_m = 0.28 (default)",
                "straps.ls1_m must be <= robot.thigh.length_m",
                "set straps.ls1_m <= 0.2 or lengthen robot.thigh.length_m",
            ],
        ),
        // The user's value is the one out of range: it leads.
        (
            "strap.toml",
            "[straps]\nls2_m = 0.5\n",
            &[],
            &["straps.ls2_m = 0.5 (your setting) and robot.shank.length_m = 0.43 (default)"],
        ),
        // Both set by the user.
        (
            "both.toml",
            "[robot.thigh]\nlength_m = 0.2\n[straps]\nls1_m = 0.3\n",
            &[],
            &["straps.ls1_m = 0.3 (your setting) and robot.thigh.length_m = 0.2 (your setting)"],
        ),
        (
            "com.toml",
            "[robot.shank]\nlength_m = 0.1\n",
            &[],
            &[
                "robot.shank.length_m = 0.1 (your setting) and robot.shank.com_m = 0.18 (default)",
                "the centre of mass lies on the link",
            ],
        ),
        (
            "payload_pos.toml",
            "[robot.shank]\nlength_m = 0.2\ncom_m = 0.1\n",
            &[],
            &["robot.shank.length_m = 0.2 (your setting) and robot.payload_position_m = 0.215 (default)"],
        ),
        (
            "np.toml",
            "[controller]\nnp = 2\n",
            &[],
            &[
                "controller.np = 2 (your setting) and controller.nc = 3 (default)",
                "set controller.nc <= 2 or raise controller.np",
            ],
        ),
        (
            "nc.toml",
            "[controller]\nnc = 1\n[multistage]\nformulation = \"coupled\"\nrobust_horizon = 2\n",
            &[],
            &["multistage.robust_horizon = 2 (your setting) and controller.nc = 1 (your setting)"],
        ),
        (
            "floor.toml",
            "[multistage]\npayloads_kg = [0.0, 1.0, 2.0, 3.0]\nprobability_floor = 0.3\n",
            &[],
            &["multistage.probability_floor = 0.3 (your setting) and multistage.payloads_kg"],
        ),
        (
            "swing.toml",
            "[trajectory]\nbase_frequency_hz = 0.1\n",
            &[],
            &["trajectory.base_frequency_hz = 0.1 (your setting) and trajectory.frequency_swing_hz = 0.2 (default)"],
        ),
        // A flag against a file value.
        (
            "dt.toml",
            "[timing]\ndt = 0.5\n",
            &["--duration", "0.1"],
            &[
                "--duration: conflicting values: timing.duration_2dof_s = 0.1 (set by --duration) \
                 and timing.dt = 0.5 (your setting)",
                "shorten timing.dt",
            ],
        ),
    ];
    for (name, toml, extra, needles) in cases {
        let out = check(name, toml, extra);
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(2), "{name}: {err}");
        assert!(err.starts_with("error: "), "{name}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{name}: one line: {err}");
        for n in *needles {
            assert!(err.contains(n), "{name}: `{n}` not in: {err}");
        }
    }
}
