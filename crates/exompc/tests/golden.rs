//! Acceptance figures of the simulation study (paper §4, Table 2; MODEL.md §9) on the full default
//! scenario: golden numbers pinned to a tolerance, and the qualitative claims of the issue.
//!
//! All runs are independent and go through rayon; one test builds them all so that the whole
//! set is computed once.

use exompc::config::{ControllerKind, Experiment, Formulation};
use exompc::scenario::{run_experiment, OneDof, TwoDof};
use exompc::sim::{Summary, TraceLog};
use rayon::prelude::*;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Run {
    Nmpc(f64),
    Ms(Formulation, f64),
}

fn scenario(r: Run) -> Experiment {
    let mut s = Experiment::default();
    match r {
        Run::Nmpc(p) => {
            s.controller.kind = ControllerKind::NMPC;
            s.uncertainty.payload_kg = p;
        }
        Run::Ms(f, p) => {
            s.controller.kind = ControllerKind::MSNMPC;
            s.multistage.formulation = f;
            s.uncertainty.payload_kg = p;
        }
    }
    s
}

fn thigh(s: &Summary) -> f64 {
    s.rms_force_n.thigh.unwrap()
}
fn shank(s: &Summary) -> f64 {
    s.rms_force_n.shank.unwrap()
}
fn mu(s: &Summary) -> &[f64] {
    s.mean_probability.as_deref().unwrap()
}

/// `got` within `rel` (relative) of `want`.
fn pin(what: &str, got: f64, want: f64, rel: f64, failures: &mut Vec<String>) {
    if (got - want).abs() > rel * want.abs() {
        failures.push(format!(
            "{what}: {got:.4} vs golden {want:.4} (±{:.0} %)",
            rel * 100.0
        ));
    }
}

fn check(cond: bool, what: String, failures: &mut Vec<String>) {
    if !cond {
        failures.push(what);
    }
}

const D: Formulation = Formulation::Decoupled;
const C: Formulation = Formulation::Coupled;

#[test]
#[allow(clippy::approx_constant)] // 6.28 N is a measured force, not τ
fn acceptance_figures_of_the_default_scenario() {
    let sweep: Vec<f64> = (0..=8).map(|i| 0.25 * i as f64).collect();
    let mut runs = vec![Run::Nmpc(0.0), Run::Nmpc(2.0)];
    for &p in &sweep {
        runs.push(Run::Ms(D, p));
        runs.push(Run::Ms(C, p));
    }
    let results: Vec<(Run, Summary)> = runs
        .par_iter()
        .map(|&r| {
            (
                r,
                run_experiment::<TwoDof, 2>(&scenario(r), &mut []).unwrap(),
            )
        })
        .collect();
    let get = |r: Run| &results.iter().find(|(x, _)| *x == r).unwrap().1;
    for (r, s) in &results {
        eprintln!(
            "{r:?}: thigh {:.3} shank {:.3} | δmax hip {:.3} knee {:.3} deg | μ {:?} | failures {}",
            thigh(s),
            shank(s),
            s.delta_max_deg.hip.unwrap(),
            s.delta_max_deg.knee.unwrap(),
            s.mean_probability
                .as_ref()
                .map(|p| p.iter().map(|v| format!("{v:.4}")).collect::<Vec<_>>()),
            s.solver_failures
        );
    }

    let mut fail = Vec::new();
    let f = &mut fail;
    // ---- Golden numbers (±3 % on forces and δmax, ±0.01 on probabilities). ----
    let tol = 0.03;
    let (n0, n2) = (get(Run::Nmpc(0.0)), get(Run::Nmpc(2.0)));
    let (m0, m1, m2) = (
        get(Run::Ms(D, 0.0)),
        get(Run::Ms(D, 1.0)),
        get(Run::Ms(D, 2.0)),
    );
    pin("nmpc 0 kg thigh", thigh(n0), 2.12, tol, f);
    pin("nmpc 0 kg shank", shank(n0), 4.77, tol, f);
    pin("nmpc 2 kg thigh", thigh(n2), 6.28, tol, f);
    pin("nmpc 2 kg shank", shank(n2), 11.11, tol, f);
    // The robust MS-NMPC since the ninth pass (strap-space velocity residual,
    // `[controller.robust] velocity_tracking = "strap"`, docs/ROBUSTNESS.md §4); the eighth
    // pass's joint-space residual gave 1.574 / 2.889, 1.863 / 3.100 and 2.083 / 3.291 N.
    pin("msnmpc 0 kg thigh", thigh(m0), 1.535, tol, f);
    pin("msnmpc 0 kg shank", shank(m0), 2.444, tol, f);
    pin("msnmpc 1 kg thigh", thigh(m1), 1.832, tol, f);
    pin("msnmpc 1 kg shank", shank(m1), 2.396, tol, f);
    pin("msnmpc 2 kg thigh", thigh(m2), 2.172, tol, f);
    pin("msnmpc 2 kg shank", shank(m2), 2.437, tol, f);
    for (name, s, want) in [
        ("nmpc 0 kg", n0, DELTA_NMPC_0),
        ("nmpc 2 kg", n2, DELTA_NMPC_2),
        ("msnmpc 0 kg", m0, DELTA_MS_0),
        ("msnmpc 1 kg", m1, DELTA_MS_1),
        ("msnmpc 2 kg", m2, DELTA_MS_2),
    ] {
        pin(
            &format!("{name} δmax hip"),
            s.delta_max_deg.hip.unwrap(),
            want[0],
            tol,
            f,
        );
        pin(
            &format!("{name} δmax knee"),
            s.delta_max_deg.knee.unwrap(),
            want[1],
            tol,
            f,
        );
    }
    let ptol = 0.01;
    for (name, s, want) in [
        ("msnmpc 0 kg", m0, [0.998, 0.0016, 0.0008]),
        ("msnmpc 1 kg", m1, MU_MS_1),
        ("msnmpc 2 kg", m2, MU_MS_2),
    ] {
        for (i, (g, w)) in mu(s).iter().zip(want).enumerate() {
            check(
                (g - w).abs() <= ptol,
                format!("{name} μ{}: {g:.4} vs golden {w:.4} (±{ptol})", i + 1),
                f,
            );
        }
    }

    // ---- Acceptance of the issue. ----
    check(
        mu(m0)[0] > 0.9,
        format!("μ1 at 0 kg = {:.4} ≤ 0.9", mu(m0)[0]),
        f,
    );
    check(
        mu(m2)[2] > 0.9,
        format!("μ3 at 2 kg = {:.4} ≤ 0.9", mu(m2)[2]),
        f,
    );
    check(
        mu(m1)[1] > mu(m1)[0] && mu(m1)[1] > mu(m1)[2],
        format!("μ2 not the largest at 1 kg: {:?}", mu(m1)),
        f,
    );
    for form in [D, C] {
        let base = get(Run::Ms(form, 0.0));
        for &p in &sweep {
            let s = get(Run::Ms(form, p));
            check(
                thigh(s) <= 1.5 * thigh(base) && shank(s) <= 1.5 * shank(base),
                format!(
                    "msnmpc {form:?} {p} kg not stable: thigh {:.3} shank {:.3} vs 0 kg {:.3} {:.3}",
                    thigh(s),
                    shank(s),
                    thigh(base),
                    shank(base)
                ),
                f,
            );
        }
    }
    // At 0 kg the plain NMPC has the exact model; the robust MS-NMPC must be no worse than
    // 1.1× its forces (issue 10's bound; with the strap observer of the seventh pass and the
    // strap-space velocity residual of the ninth it is lower: 1.54 / 2.44 N against
    // 2.12 / 4.77 N).
    check(
        thigh(m0) <= 1.1 * thigh(n0) && shank(m0) <= 1.1 * shank(n0),
        format!(
            "msnmpc at 0 kg above 1.1× nmpc: {:.3}/{:.3} vs {:.3}/{:.3}",
            thigh(m0),
            shank(m0),
            thigh(n0),
            shank(n0)
        ),
        f,
    );
    check(
        shank(n2) >= 2.5 * shank(m2),
        format!(
            "2 kg shank: nmpc {:.3} < 2.5 × msnmpc {:.3}",
            shank(n2),
            shank(m2)
        ),
        f,
    );
    check(
        thigh(n2) >= 2.0 * thigh(m2),
        format!(
            "2 kg thigh: nmpc {:.3} < 2 × msnmpc {:.3}",
            thigh(n2),
            thigh(m2)
        ),
        f,
    );
    for (r, s) in &results {
        check(
            s.limit_violations == 0,
            format!("{r:?}: {} limit violations", s.limit_violations),
            f,
        );
    }

    assert!(
        fail.is_empty(),
        "acceptance failures:\n  {}",
        fail.join("\n  ")
    );
}

/// 1-DOF knee experiment (paper §4.2) at 2 kg: the 2 kg scenario is identified (μ3 > 0.9) at
/// every step from 17 s on.
#[test]
fn one_dof_identifies_the_payload() {
    let s = scenario(Run::Ms(D, 2.0));
    s.validate().unwrap();
    let mut log = TraceLog::<1>::default();
    let sum = run_experiment::<OneDof, 1>(&s, &mut [&mut log]).unwrap();
    assert_eq!(sum.steps, 3000);
    assert_eq!(sum.limit_violations, 0);
    let late: Vec<_> = log.rows.iter().filter(|r| r.t >= 17.0 - 1e-9).collect();
    assert!(!late.is_empty());
    let worst = late
        .iter()
        .map(|r| r.probabilities[2])
        .fold(f64::INFINITY, f64::min);
    eprintln!(
        "1-DOF 2 kg: shank RMS {:.3} N, μ {:?}, min μ3 after 17 s {worst:.4}",
        shank(&sum),
        sum.mean_probability
    );
    assert!(worst > 0.9, "μ3 drops to {worst} after 17 s");
}

// Measured on the default scenario (δmax in degrees; MODEL.md §9 gives the forces and the matching
// probabilities, the rest was measured when this test was written). The MS-NMPC values are
// the robust default's since issue 10's seventh pass (strap observer; before: δmax 0.968 /
// 2.178, 1.138 / 1.730, 1.281 / 1.533 deg at 0 / 1 / 2 kg, μ at 1 kg 0.001 / 0.987 / 0.012).
const DELTA_NMPC_0: [f64; 2] = [0.924, 2.018];
const DELTA_NMPC_2: [f64; 2] = [3.144, 8.249];
// Ninth pass (the eighth's: [0.644, 0.930], [0.760, 0.924], [0.847, 0.920]).
const DELTA_MS_0: [f64; 2] = [0.630, 0.666];
const DELTA_MS_1: [f64; 2] = [0.843, 0.611];
const DELTA_MS_2: [f64; 2] = [1.031, 0.588];
const MU_MS_1: [f64; 3] = [0.0003, 0.9995, 0.0003];
const MU_MS_2: [f64; 3] = [0.0003, 0.0036, 0.9962];
