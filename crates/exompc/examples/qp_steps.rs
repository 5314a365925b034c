//! Closed-loop control steps of the 2-DOF multi-stage NMPC (decoupled, or coupled with a fifth
//! argument `coupled`) for one horizon, scenario count and QP backend, for instruction counts per step under callgrind (docs/PERFORMANCE.md):
//!
//! ```text
//! cargo build --release --example qp_steps
//! valgrind --tool=callgrind --toggle-collect='*MultiStage*as*Controller*step*' \
//!     target/release/examples/qp_steps 20 9 structured 100
//! ```
//!
//! Arguments: `Np = Nc`, scenarios, `dense | structured`, steps (after 20 warm-up steps, which
//! also run under the toggle; subtract a run with fewer steps for a per-step figure), and
//! optionally `decoupled | coupled` (default decoupled) and the Hessian model
//! `gauss_newton | structured_secant | exact` (default: the scenario default).
//!
//! `qp_steps nmpc <steps>` and `qp_steps msnmpc <steps>` step the default scenario's own NMPC
//! and MS-NMPC controllers instead (toggle `'*Nmpc*as*Controller*step*'` for the NMPC).

use exompc::config::{ControllerKind, Experiment, Formulation};
use exompc::control::{Controller, QpBackend};
use exompc::scenario::{build_controller, plant_params, uncertainty, Dof, TwoDof};
use exompc::sim::{Plant, Sensors};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let arg = |i: usize, d: &str| args.get(i).cloned().unwrap_or_else(|| d.to_string());
    let default_kind = match arg(1, "").as_str() {
        "nmpc" => Some(ControllerKind::NMPC),
        "msnmpc" => Some(ControllerKind::MSNMPC),
        _ => None,
    };
    if let Some(kind) = default_kind {
        let steps: usize = arg(2, "100").parse().expect("steps");
        let s = Experiment::default();
        let c = build_controller::<TwoDof, 2>(&s, kind).expect("controller");
        let iters = run(&s, c, steps);
        println!(
            "default scenario {kind} steps={steps} SQP iterations/step={:.2}",
            iters as f64 / steps as f64
        );
        return;
    }
    let n: usize = arg(1, "20").parse().expect("Np = Nc");
    let ns: usize = arg(2, "9").parse().expect("scenarios");
    let qp = match arg(3, "structured").as_str() {
        "dense" => QpBackend::Dense,
        "structured" => QpBackend::Structured,
        other => panic!("backend `{other}`: dense or structured"),
    };
    let steps: usize = arg(4, "100").parse().expect("steps");
    let formulation = match arg(5, "decoupled").as_str() {
        "decoupled" => Formulation::Decoupled,
        "coupled" => Formulation::Coupled,
        other => panic!("formulation `{other}`: decoupled or coupled"),
    };
    let mut s = Experiment::default();
    s.controller.sqp.hessian = match arg(6, "default").as_str() {
        "default" => s.controller.sqp.hessian,
        "gauss_newton" => exompc::control::HessianSetting::GaussNewton,
        "structured_secant" => exompc::control::HessianSetting::StructuredSecant,
        "exact" => exompc::control::HessianSetting::Exact,
        other => panic!("hessian `{other}`: gauss_newton, structured_secant or exact"),
    };
    s.controller.kind = ControllerKind::MSNMPC;
    s.controller.np = n;
    s.controller.nc = n;
    s.controller.sqp.qp = qp;
    s.multistage.formulation = formulation;
    s.multistage.parallel = false;
    s.multistage.payloads_kg = (0..ns)
        .map(|i| {
            if ns == 1 {
                0.0
            } else {
                2.0 * i as f64 / (ns - 1) as f64
            }
        })
        .collect();
    s.multistage.probability_floor = s.multistage.probability_floor.min(0.5 / ns as f64);
    let c = build_controller::<TwoDof, 2>(&s, ControllerKind::MSNMPC).expect("controller");
    let iters = run(&s, c, steps);
    println!(
        "Np=Nc={n} scenarios={ns} qp={:?} {:?} steps={steps} SQP iterations/step={:.2}",
        qp,
        formulation,
        iters as f64 / steps as f64
    );
}

/// 20 warm-up steps and `steps` closed-loop steps of `c` on the plant of `s`; the SQP
/// iterations summed over the `steps`.
fn run(s: &Experiment, mut c: Box<dyn Controller<2>>, steps: usize) -> u64 {
    let mut plant = Plant::new(plant_params::<TwoDof, 2>(s), TwoDof::trajectory(s));
    let mut sensors = Sensors::new(uncertainty(s), s.uncertainty.filter_window);
    let mut iters = 0u64;
    for k in 0..20 + steps {
        let st = *plant.state();
        let f = plant.strap_force();
        let (_, m) = sensors.read(plant.time(), &st.robot.q, &st.robot.qd, &f);
        let o = c.step(&m);
        if k >= 20 {
            iters += u64::from(o.iterations);
        }
        plant.step(&o.torque);
    }
    iters
}
