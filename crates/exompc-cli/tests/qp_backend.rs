//! `[controller.sqp] qp`: the three values load, a wrong one is rejected with a message naming
//! the allowed values, and an absent key keeps the default (`auto`). `rti`: loads, reaches the
//! solver settings, defaults to `false`. `hessian`: `auto` by default, every model loads.

use exompc::config::Experiment;
use exompc::control::QpBackend;
use exompc_cli::io::{get_key, parse_value, set_key};

#[test]
fn qp_backend_key_round_trips_and_rejects_unknown_values() {
    let s = Experiment::default();
    assert_eq!(s.controller.sqp.qp, QpBackend::Auto);
    for (text, want) in [
        ("\"dense\"", QpBackend::Dense),
        ("\"structured\"", QpBackend::Structured),
        ("\"auto\"", QpBackend::Auto),
    ] {
        let t = set_key(&s, "controller.sqp.qp", parse_value(text)).unwrap();
        assert_eq!(t.controller.sqp.qp, want);
        let back = get_key(&t, "controller.sqp.qp").unwrap().unwrap();
        assert_eq!(back, parse_value(text));
    }
    let err = set_key(&s, "controller.sqp.qp", parse_value("\"sparse\"")).unwrap_err();
    assert!(
        err.contains("dense") && err.contains("structured") && err.contains("auto"),
        "{err}"
    );
}

#[test]
fn rti_key_loads_and_reaches_the_solver_settings() {
    let s = Experiment::default();
    assert!(!s.controller.sqp.rti);
    assert!(!exompc::scenario::nmpc_settings(&s).sqp.real_time_iteration);
    let t = set_key(&s, "controller.sqp.rti", parse_value("true")).unwrap();
    assert!(t.controller.sqp.rti);
    assert!(exompc::scenario::nmpc_settings(&t).sqp.real_time_iteration);
    assert!(set_key(&s, "controller.sqp.rti", parse_value("\"yes\"")).is_err());
}

#[test]
fn hessian_key_defaults_to_auto_and_loads_every_model() {
    use exompc::control::HessianSetting;
    let s = Experiment::default();
    assert_eq!(s.controller.sqp.hessian, HessianSetting::Auto);
    for (text, want) in [
        ("\"auto\"", HessianSetting::Auto),
        ("\"structured_secant\"", HessianSetting::StructuredSecant),
        ("\"gauss_newton\"", HessianSetting::GaussNewton),
        ("\"exact\"", HessianSetting::Exact),
    ] {
        let t = set_key(&s, "controller.sqp.hessian", parse_value(text)).unwrap();
        assert_eq!(t.controller.sqp.hessian, want);
        let back = get_key(&t, "controller.sqp.hessian").unwrap().unwrap();
        assert_eq!(back, parse_value(text));
    }
    let err = set_key(&s, "controller.sqp.hessian", parse_value("\"newton\"")).unwrap_err();
    assert!(
        err.contains("auto") && err.contains("structured_secant"),
        "{err}"
    );
}
