//! The multi-stage NMPC (paper §3.2, eqs. 10-13): the coupled scenario tree against the plain
//! NMPC and the decoupled blend, limits under arbitrary measurements, and the probabilities.

mod common;
use common::{closed_loop, measurement};
use exompc::config::{ControllerKind, Experiment, Formulation, IntentEstimate};
use exompc::control::{horizon_inputs, Controller, NmpcCore};
use exompc::model::JointState;
use exompc::scenario::build_multistage;
use exompc::scenario::{
    initial_torque, intent, limits, multistage_nmpc_settings, plant_params, prediction_model,
    run_experiment, uncertainty, Dof, TwoDof,
};
use exompc::sim::{Plant, Sensors, TraceLog};
use nalgebra::Vector2;
use proptest::prelude::*;

type V2 = Vector2<f64>;

fn ms_scenario(payloads: &[f64], formulation: Formulation) -> Experiment {
    let mut s = Experiment::default();
    s.controller.kind = ControllerKind::MSNMPC;
    s.multistage.payloads_kg = payloads.to_vec();
    s.multistage.formulation = formulation;
    // The equivalences below are between optima; solve tightly so that the paths the solvers
    // take (which differ between the formulations) do not show in the comparison. At the
    // default KKT 1e-8 the flattest cost directions (curvature ~1e-5) leave ~1e-5 N·m of play.
    s.controller.sqp.kkt_tolerance = 1e-12;
    s.validate().unwrap();
    s
}

fn controller(s: &Experiment) -> Box<dyn Controller<2>> {
    build_multistage::<TwoDof, 2, 6, 4>(s, initial_torque::<TwoDof, 2>(s)).unwrap()
}

#[test]
fn coupled_with_one_scenario_equals_plain_nmpc() {
    let mut s = ms_scenario(&[0.0], Formulation::Coupled);
    s.uncertainty.payload_kg = 1.0;
    // The plain NMPC below takes the paper's intent estimate (eqs. 5-6).
    s.controller.robust.intent_estimate = IntentEstimate::Paper;
    let mut ms = controller(&s);
    let model = prediction_model::<TwoDof, 2>(&s, 0.0);
    // The same NMPC settings as the multi-stage NMPC's scenarios (the robust method's
    // strap-space velocity residual included).
    let mut core = NmpcCore::new(model, &multistage_nmpc_settings(&s)).unwrap();
    let (lim, int) = (limits(&s), intent(&s));
    let mut worst = 0.0f64;
    closed_loop(&s, ms.as_mut(), 500, |k, m, prev, torque, c| {
        assert_eq!(c.probabilities().unwrap(), &[1.0]);
        // The plain NMPC of eq. 7 with the same disturbance estimate the scenario used.
        let d = c.disturbance(0).unwrap();
        let inputs = horizon_inputs(&int, &model, m, d);
        core.solve(JointState { q: m.q, qd: m.qd }, prev, inputs, &lim);
        let want = lim.clamp(&prev, &(prev + core.first_increment()));
        let diff = (torque - want).amax();
        worst = worst.max(diff);
        assert!(
            diff <= 1e-6,
            "step {k}: coupled {torque:?} vs nmpc {want:?}"
        );
    });
    eprintln!("worst |T_coupled - T_nmpc| = {worst:e}");
}

#[test]
fn coupled_with_identical_scenarios_equals_decoupled() {
    let sc = ms_scenario(&[1.0, 1.0, 1.0], Formulation::Coupled);
    let sd = ms_scenario(&[1.0, 1.0, 1.0], Formulation::Decoupled);
    let mut coupled = controller(&sc);
    let mut decoupled = controller(&sd);
    let mut worst = 0.0f64;
    closed_loop(&sc, coupled.as_mut(), 500, |k, m, _prev, torque, c| {
        let out = decoupled.step(m);
        let diff = (torque - out.torque).amax();
        worst = worst.max(diff);
        assert!(
            diff <= 1e-6,
            "step {k}: coupled {torque:?} vs decoupled {:?}",
            out.torque
        );
        let (pc, pd) = (
            c.probabilities().unwrap(),
            decoupled.probabilities().unwrap(),
        );
        for (a, b) in pc.iter().zip(pd) {
            assert!((a - b).abs() <= 1e-9 && (a - 1.0 / 3.0).abs() <= 1e-9);
        }
    });
    eprintln!("worst |T_coupled - T_decoupled| = {worst:e}");
}

#[test]
fn probabilities_sum_to_one_and_respect_the_floor_in_closed_loop() {
    for (payload, formulation) in [(2.0, Formulation::Decoupled), (1.0, Formulation::Coupled)] {
        let mut s = ms_scenario(&[0.0, 1.0, 2.0], formulation);
        s.uncertainty.payload_kg = payload;
        s.timing.duration_2dof_s = 5.0;
        let floor = s.multistage.probability_floor;
        let mut log = TraceLog::<2>::default();
        let sum = run_experiment::<TwoDof, 2>(&s, &mut [&mut log]).unwrap();
        assert_eq!(sum.limit_violations, 0);
        assert_eq!(log.rows.len(), 500);
        for row in &log.rows {
            let p = &row.probabilities;
            assert_eq!(p.len(), 3);
            let total: f64 = p.iter().sum();
            assert!((total - 1.0).abs() <= 1e-12, "t {}: sum {total}", row.t);
            assert!(
                p.iter()
                    .all(|v| v.is_finite() && *v >= floor * (1.0 - 1e-12)),
                "t {}: {p:?}",
                row.t
            );
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Whatever the measurements, the blended (or coupled) torque satisfies every limit and the
    /// probabilities stay a distribution above the floor.
    #[test]
    fn multistage_torque_always_within_limits(
        coupled in any::<bool>(),
        ms in prop::collection::vec(measurement(), 1..5),
    ) {
        let f = if coupled { Formulation::Coupled } else { Formulation::Decoupled };
        let s = ms_scenario(&[0.0, 1.0, 2.0], f);
        let lim = limits(&s);
        let mut c = controller(&s);
        for m in &ms {
            let prev = c.previous_torque();
            let out = c.step(m);
            prop_assert!(lim.admits(&prev, &out.torque), "{:?} -> {:?}", prev, out);
            let p = c.probabilities().unwrap();
            let total: f64 = p.iter().sum();
            prop_assert!((total - 1.0).abs() <= 1e-9, "{:?}", p);
            prop_assert!(p.iter().all(|v| *v >= s.multistage.probability_floor * (1.0 - 1e-12)));
        }
    }
}

/// After a gap in the data (steps the controller was not called for, as when a supervisor
/// rejects bad samples) the EKF bank resumes from the measurement: the probabilities and the
/// disturbance estimates are carried across the gap unchanged, and the true scenario (2 kg)
/// keeps a mean probability above 0.9 afterwards with the paper's method. The robust default's
/// oscillation detector sees the transient after the 0.2-s torque hold and engages its
/// filter-aware mode, whose EKF input is the Smith-predicted strap torque: there the mean is
/// lower (measured 0.77), asserted above 0.7.
#[test]
fn ekf_bank_resumes_after_a_gap_in_the_data() {
    for (method, min_mean) in [
        (exompc::config::Method::Paper, 0.9),
        (exompc::config::Method::Robust, 0.7),
    ] {
        ekf_bank_resumes_after_a_gap(method, min_mean);
    }
}

fn ekf_bank_resumes_after_a_gap(method: exompc::config::Method, min_mean: f64) {
    let mut s = ms_scenario(&[0.0, 1.0, 2.0], Formulation::Decoupled);
    s.uncertainty.payload_kg = 2.0;
    s.controller.method = method;
    let mut c = controller(&s);
    let mut plant = Plant::new(plant_params::<TwoDof, 2>(&s), TwoDof::trajectory(&s));
    let mut sensors = Sensors::new(uncertainty(&s), s.uncertainty.filter_window);
    let (gap_start, gap_len) = (400, 20);
    let mut before: Option<(Vec<f64>, Vec<V2>)> = None;
    let mut hold = V2::zeros();
    let (mut after_sum, mut after_n) = (0.0, 0);
    for k in 0..700 {
        let st = *plant.state();
        let f = plant.strap_force();
        let (_, m) = sensors.read(plant.time(), &st.robot.q, &st.robot.qd, &f);
        if (gap_start..gap_start + gap_len).contains(&k) {
            // The controller is not called; the last torque is held.
            plant.step(&hold);
            continue;
        }
        let out = c.step(&m);
        hold = out.torque;
        let p = c.probabilities().unwrap().to_vec();
        let d: Vec<V2> = (0..3).map(|i| c.disturbance(i).unwrap()).collect();
        if k == gap_start - 1 {
            before = Some((p.clone(), d.clone()));
        }
        if k == gap_start + gap_len {
            let (pb, db) = before.clone().unwrap();
            assert_eq!(p, pb, "probabilities must be carried across the gap");
            for (a, b) in d.iter().zip(&db) {
                assert!((a - b).amax() == 0.0, "d̂ must be carried across the gap");
            }
        }
        if k > gap_start + gap_len + 50 {
            // Eq. 10 with c1 = 100 can flip the probabilities for a step at a velocity
            // reversal, so the claim is on the average, as in the paper's Table 2.
            after_sum += p[2];
            after_n += 1;
        }
        plant.step(&out.torque);
    }
    let mean = after_sum / after_n as f64;
    assert!(mean > min_mean, "{method:?}: mean μ3 after the gap {mean}");
}
