//! `controller.k1 = "auto"` / `controller.k2 = "auto"`: intent gains derived from the strap
//! stiffness (`exompc::control::IntentGain`), read from a config file or `--set`, and the
//! closed loop they give equal to the same gains written as numbers.

use exompc::config::{ControllerKind, Experiment, GainSetting};
use exompc::scenario::{run_experiment, TwoDof};
use exompc_cli::io::{parse_scenario, parse_value, set_key};

#[test]
fn a_config_reads_auto_numbers_and_mixes() {
    let d = Experiment::default();
    assert_eq!(d.controller.k1, GainSetting::Value(0.005));
    assert_eq!(d.controller.k2, GainSetting::Value(0.05));
    let s = parse_scenario("[controller]\nk1 = \"auto\"\nk2 = \"auto\"\n").unwrap();
    assert_eq!(s.controller.k1, GainSetting::Auto);
    assert_eq!(s.controller.k2, GainSetting::Auto);
    let s = parse_scenario("[controller]\nk1 = 0.004\nk2 = \"auto\"\n").unwrap();
    assert_eq!(s.controller.k1, GainSetting::Value(0.004));
    assert_eq!(s.controller.k2, GainSetting::Auto);
    let s = parse_scenario("[controller]\nk1 = 0\n").unwrap();
    assert_eq!(s.controller.k1, GainSetting::Value(0.0));
    let s = set_key(&s, "controller.k1", parse_value("auto")).unwrap();
    assert_eq!(s.controller.k1, GainSetting::Auto);
    let s = set_key(&s, "controller.k2", parse_value("0.03")).unwrap();
    assert_eq!(s.controller.k2, GainSetting::Value(0.03));
}

#[test]
fn a_wrong_gain_names_the_key_and_the_allowed_values() {
    let e = parse_scenario("[controller]\nk1 = \"fast\"\n").unwrap_err();
    assert!(
        e.contains("k1") && e.contains("fast") && e.contains("auto"),
        "{e}"
    );
    let e = parse_scenario("[controller]\nk2 = -0.1\n").unwrap_err();
    assert!(e.contains("controller.k2") && e.contains(">= 0"), "{e}");
    let e = parse_scenario("[controller]\nk1 = true\n").unwrap_err();
    assert!(e.contains("k1"), "{e}");
}

fn rms(s: &Experiment) -> (f64, f64) {
    let sum = run_experiment::<TwoDof, 2>(s, &mut []).unwrap();
    (
        sum.rms_force_n.thigh.unwrap(),
        sum.rms_force_n.shank.unwrap(),
    )
}

/// At the default straps `"auto"` is the paper's 0.005 / 0.05 bit for bit; with straps twice as
/// stiff it is 0.0025 / 0.025 (the loop gain `K1 ks J` kept), for the NMPC and the PD.
#[test]
fn auto_gains_run_the_loop_of_the_stiffness_scaled_numbers() {
    for kind in [ControllerKind::NMPC, ControllerKind::PD] {
        for (ks, cs, k1, k2) in [(937.5, 93.7, 0.005, 0.05), (1875.0, 187.4, 0.0025, 0.025)] {
            let mut auto = Experiment::default();
            auto.controller.kind = kind;
            auto.timing.duration_2dof_s = 2.0;
            auto.uncertainty.payload_kg = 1.0;
            auto.straps.stiffness = ks;
            auto.straps.damping = cs;
            auto.controller.k1 = GainSetting::Auto;
            auto.controller.k2 = GainSetting::Auto;
            let mut fixed = auto.clone();
            fixed.controller.k1 = GainSetting::Value(k1);
            fixed.controller.k2 = GainSetting::Value(k2);
            let mut paper = auto.clone();
            paper.controller.k1 = GainSetting::Value(0.005);
            paper.controller.k2 = GainSetting::Value(0.05);
            let (a, f, p) = (rms(&auto), rms(&fixed), rms(&paper));
            assert_eq!(a, f, "{kind:?} ks {ks}: auto vs k1 = {k1}");
            if ks != 937.5 {
                assert_ne!(
                    a, p,
                    "{kind:?} ks {ks}: auto should differ from the fixed 0.005"
                );
            }
        }
    }
}
