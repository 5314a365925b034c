//! The trace's columns: one table ([`TRACE_COLUMNS`]: name, unit, meaning, which
//! [`StepRecord`] field) from which the trace CSV's header and rows ([`csv_header`],
//! [`csv_row`]: `simulate`, `sweep`, `soak`, `run`, `virtual-robot`, the firmware), the Python
//! trace's keys and the docs' column table ([`columns_markdown`]) all come.
//!
//! CSV order: the table's CSV columns in table order; a run of consecutive columns with the
//! same [`Per`] is written index-major (`q_robot_hip, …, torque_human_hip, q_robot_knee, …`).

use super::closed_loop::StepRecord;
use alloc::format;
use alloc::string::String;
use alloc::vec::Vec;
use core::fmt::Write as _;

/// What one entry of [`TRACE_COLUMNS`] repeats over.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Per {
    /// One value per step: CSV column `name`.
    Step,
    /// One value per joint `J` ([`joint_names`]): CSV columns `name_J`.
    Joint,
    /// One value per strap `S` ([`strap_names`]): CSV columns `name_S`.
    Strap,
    /// One value per scenario `K` (its number `1, 2, …` or its name): CSV columns `name_K`.
    Scenario,
    /// One value per scenario `K` and joint `J`: CSV columns `name_K_J`.
    ScenarioJoint,
}

/// The [`StepRecord`] field a column reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Field {
    /// [`StepRecord::t`].
    Time,
    /// [`StepRecord::robot`]`.q`.
    RobotAngle,
    /// [`StepRecord::robot`]`.qd`.
    RobotVelocity,
    /// [`StepRecord::human`]`.q`.
    HumanAngle,
    /// [`StepRecord::human`]`.qd`.
    HumanVelocity,
    /// [`StepRecord::desired`].
    Desired,
    /// [`StepRecord::torque_robot`].
    TorqueRobot,
    /// [`StepRecord::torque_prev`].
    TorquePrev,
    /// [`StepRecord::torque_human`].
    TorqueHuman,
    /// [`StepRecord::force_true`].
    ForceTrue,
    /// [`StepRecord::force_measured`].
    ForceMeasured,
    /// [`StepRecord::probabilities`].
    Probability,
    /// [`StepRecord::disturbances`].
    Disturbance,
    /// [`StepRecord::status`] (CSV: its name; Python: its code).
    Status,
    /// [`StepRecord::iterations`].
    Iterations,
    /// [`StepRecord::step_time_us`].
    StepTime,
    /// [`StepRecord::within_limits`].
    WithinLimits,
}

/// One entry of the trace's column table.
#[derive(Clone, Copy, Debug)]
pub struct TraceColumn {
    /// The record field.
    pub field: Field,
    /// What the column repeats over.
    pub per: Per,
    /// CSV column name (prefix before `_J`, `_S`, `_K`), `None` when not in the CSV.
    pub csv: Option<&'static str>,
    /// Key of the Python trace dict (`exompc.simulate(...)["trace"]`), `None` when not there.
    pub python: Option<&'static str>,
    /// Unit (`"-"` for none).
    pub unit: &'static str,
    /// Meaning.
    pub meaning: &'static str,
}

const fn col(
    field: Field,
    per: Per,
    csv: Option<&'static str>,
    python: Option<&'static str>,
    unit: &'static str,
    meaning: &'static str,
) -> TraceColumn {
    TraceColumn {
        field,
        per,
        csv,
        python,
        unit,
        meaning,
    }
}

/// The trace's columns (paper §4.1's quantities per control period `k`).
#[rustfmt::skip]
pub const TRACE_COLUMNS: [TraceColumn; 17] = {
    use Field as F;
    use Per as P;
    [
        col(F::Time, P::Step, Some("t"), Some("t"), "s", "time t_k of the step"),
        col(F::RobotAngle, P::Joint, Some("q_robot"), Some("q_robot"), "rad", "robot joint angle (run: the raw sample)"),
        col(F::RobotVelocity, P::Joint, Some("qd_robot"), Some("qd_robot"), "rad/s", "robot joint velocity (run: the raw sample)"),
        col(F::HumanAngle, P::Joint, Some("q_human"), Some("q_human"), "rad", "human joint angle (NaN where unknown: run)"),
        col(F::HumanVelocity, P::Joint, Some("qd_human"), Some("qd_human"), "rad/s", "human joint velocity (NaN where unknown)"),
        col(F::Desired, P::Joint, Some("q_desired"), Some("q_desired"), "rad", "the human's desired angle q_d(t_k) (NaN where unknown)"),
        col(F::TorqueRobot, P::Joint, Some("torque_robot"), Some("torque_robot"), "N·m", "robot torque T_R(k) applied over the period"),
        col(F::TorqueHuman, P::Joint, Some("torque_human"), Some("torque_human"), "N·m", "human torque T_H(t_k) (NaN where unknown)"),
        col(F::TorquePrev, P::Joint, None, Some("torque_prev"), "N·m", "previous robot torque T_R(k−1)"),
        col(F::ForceTrue, P::Strap, Some("force_true"), Some("force_true"), "N", "true strap force (run: NaN; virtual-robot: the plant's)"),
        col(F::ForceMeasured, P::Strap, Some("force_measured"), Some("force_measured"), "N", "filtered measured strap force the controller saw"),
        col(F::Probability, P::Scenario, Some("mu"), Some("probabilities"), "-", "scenario probability μ_K (multi-stage controllers only)"),
        col(F::Disturbance, P::ScenarioJoint, Some("dist"), Some("disturbances"), "N·m", "scenario K's disturbance estimate at joint J"),
        col(F::Status, P::Step, Some("status"), Some("status"), "-", "step outcome, its StepStatus name (Python adds the codes as `status_code`)"),
        col(F::Iterations, P::Step, Some("iterations"), Some("iterations"), "-", "SQP iterations of the step"),
        col(F::StepTime, P::Step, Some("step_us"), Some("step_time_us"), "µs", "time of the controller's step (firmware: emulated, 1 ns per instruction)"),
        col(F::WithinLimits, P::Step, None, Some("within_limits"), "-", "torque within both limits (checked outside the controller)"),
    ]
};

/// Joint names for `n` joints (`hip`, `knee`; 1-DOF: `knee`).
pub fn joint_names(n: usize) -> &'static [&'static str] {
    if n == 1 {
        &["knee"]
    } else {
        &["hip", "knee"]
    }
}

/// Strap names for `n` joints (`thigh`, `shank`; 1-DOF: `shank`).
pub fn strap_names(n: usize) -> &'static [&'static str] {
    if n == 1 {
        &["shank"]
    } else {
        &["thigh", "shank"]
    }
}

/// The CSV columns in order, each with the index it repeats over (`(column, i)`, `i` the joint,
/// strap or scenario index; for [`Per::ScenarioJoint`] `scenario · n + joint`). Allocates
/// nothing (it runs once per trace row).
fn csv_cells(n: usize, scenarios: usize, mut f: impl FnMut(&TraceColumn, usize)) {
    let cols = &TRACE_COLUMNS;
    let mut a = 0;
    while a < cols.len() {
        if cols[a].csv.is_none() {
            a += 1;
            continue;
        }
        // A run of CSV columns with the same `per` (columns not in the CSV are passed over).
        let per = cols[a].per;
        let mut b = a;
        while b < cols.len() && (cols[b].per == per || cols[b].csv.is_none()) {
            b += 1;
        }
        let count = match per {
            Per::Step => 1,
            Per::Joint | Per::Strap => n,
            Per::Scenario => scenarios,
            Per::ScenarioJoint => scenarios * n,
        };
        for i in 0..count {
            for c in cols[a..b].iter().filter(|c| c.csv.is_some()) {
                f(c, i);
            }
        }
        a = b;
    }
}

/// The CSV header of a trace with `n` joints and one scenario per key of `scenarios`
/// (`1, 2, …` or the scenarios' names).
pub fn csv_header(n: usize, scenarios: &[String]) -> Vec<String> {
    let (joints, straps) = (joint_names(n), strap_names(n));
    let mut h = Vec::new();
    csv_cells(n, scenarios.len(), |c, i| {
        let name = c.csv.unwrap_or_default();
        h.push(match c.per {
            Per::Step => String::from(name),
            Per::Joint => format!("{name}_{}", joints[i]),
            Per::Strap => format!("{name}_{}", straps[i]),
            Per::Scenario => format!("{name}_{}", scenarios[i]),
            Per::ScenarioJoint => format!("{name}_{}_{}", scenarios[i / n], joints[i % n]),
        });
    });
    h
}

/// Append the CSV row of `r` (`scenarios` scenario columns; a missing value is NaN) and a
/// newline to `line`. Numbers in Rust's shortest round-trip form.
pub fn csv_row<const N: usize>(r: &StepRecord<'_, N>, scenarios: usize, line: &mut String) {
    let mut first = true;
    csv_cells(N, scenarios, |c, i| {
        if !first {
            line.push(',');
        }
        first = false;
        let _ = match c.field {
            Field::Status => write!(line, "{}", r.status.name()),
            Field::Iterations => write!(line, "{}", r.iterations),
            _ => write!(line, "{}", value(r, c.field, i)),
        };
    });
    line.push('\n');
}

/// The value of `field` at index `i` (joint, strap, scenario or `scenario · N + joint`) of `r`;
/// NaN where the record has none. Status and flags as numbers (code, 0/1).
pub fn value<const N: usize>(r: &StepRecord<'_, N>, field: Field, i: usize) -> f64 {
    let v = |x: &nalgebra::SVector<f64, N>| x.get(i).copied().unwrap_or(f64::NAN);
    match field {
        Field::Time => r.t,
        Field::RobotAngle => v(&r.robot.q),
        Field::RobotVelocity => v(&r.robot.qd),
        Field::HumanAngle => v(&r.human.q),
        Field::HumanVelocity => v(&r.human.qd),
        Field::Desired => v(&r.desired),
        Field::TorqueRobot => v(&r.torque_robot),
        Field::TorquePrev => v(&r.torque_prev),
        Field::TorqueHuman => v(&r.torque_human),
        Field::ForceTrue => v(&r.force_true),
        Field::ForceMeasured => v(&r.force_measured),
        Field::Probability => r
            .probabilities
            .and_then(|p| p.get(i).copied())
            .unwrap_or(f64::NAN),
        Field::Disturbance => r
            .disturbances
            .and_then(|d| d.get(i / N.max(1)))
            .map_or(f64::NAN, |d| d[i % N.max(1)]),
        Field::Status => f64::from(r.status.code()),
        Field::Iterations => f64::from(r.iterations),
        Field::StepTime => r.step_time_us,
        Field::WithinLimits => f64::from(u8::from(r.within_limits)),
    }
}

/// The docs' column table (Markdown): CSV name, Python key, unit, meaning, one row per entry.
pub fn columns_markdown() -> String {
    let mut s = String::from("| CSV column | Python key | Unit | Meaning |\n|---|---|---|---|\n");
    for c in &TRACE_COLUMNS {
        let suffix = match c.per {
            Per::Step => "",
            Per::Joint => "_J",
            Per::Strap => "_S",
            Per::Scenario => "_K",
            Per::ScenarioJoint => "_K_J",
        };
        let csv = c
            .csv
            .map_or(String::from("—"), |n| format!("`{n}{suffix}`"));
        let py = c.python.map_or(String::from("—"), |n| format!("`{n}`"));
        let _ = writeln!(s, "| {csv} | {py} | {} | {} |", c.unit, c.meaning);
    }
    s
}
