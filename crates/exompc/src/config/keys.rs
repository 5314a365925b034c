//! The scenario's keys explained: unit, one-line meaning, allowed values and where the key
//! comes from (a `docs/MODEL.md` section or another document), for every key and table of a
//! scenario file. `exompc config` prints these as comments and `exompc config --explain KEY`
//! shows one entry. Tests check that every key of the scenario has an entry, that every entry
//! names a key that exists, and that the allowed ranges agree with [`Experiment::validate`]
//! (probing each end of each range).
//!
//! [`Experiment::validate`]: super::Experiment::validate

use super::{scenarios, Channel, FaultKind, MAX_CONTROL_STEPS, MAX_PAYLOAD_KG, MAX_SCENARIOS};
use alloc::{format, string::String, vec::Vec};
use core::fmt::Write as _;

/// One end of an allowed real or integer range: a number or another key's value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Limit {
    /// A fixed number.
    Num(f64),
    /// The value of another key (dotted path), e.g. `robot.thigh.length_m`.
    Key(&'static str),
    /// `1 / (number of entries of the list at this key)`.
    InverseLen(&'static str),
}

impl core::fmt::Display for Limit {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Limit::Num(v) => write!(f, "{v}"),
            Limit::Key(k) => f.write_str(k),
            Limit::InverseLen(k) => write!(f, "1/len({k})"),
        }
    }
}

/// One end of a range: where, and whether the end itself is allowed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct End {
    /// The limit.
    pub at: Limit,
    /// `true` for `[`/`]`, `false` for `(`/`)`.
    pub inclusive: bool,
}

/// The values a key accepts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Allowed {
    /// A table of keys (`[robot.thigh]`).
    Table,
    /// Any number of `[[...]]` tables.
    Tables,
    /// A finite real number between two optional ends.
    Real {
        /// Lower end (`None`: unbounded).
        lo: Option<End>,
        /// Upper end (`None`: unbounded).
        hi: Option<End>,
    },
    /// An integer in `lo..=hi`.
    Int {
        /// Smallest value.
        lo: u64,
        /// Largest value.
        hi: Limit,
    },
    /// A list of reals: `min_len..=max_len` entries, each finite in `[lo, hi]`.
    List {
        /// Fewest entries.
        min_len: usize,
        /// Most entries.
        max_len: usize,
        /// Smallest entry.
        lo: f64,
        /// Largest entry.
        hi: f64,
    },
    /// A finite real number `>= lo`, or the word `word` (a TOML string), e.g. `"auto"`.
    RealOrWord {
        /// Smallest number.
        lo: f64,
        /// The word.
        word: &'static str,
    },
    /// One of these words (a TOML string).
    Choice(&'static [&'static str]),
    /// `true` or `false`.
    Bool,
    /// A file path (a TOML string), relative to the config file's folder.
    Path,
    /// The name of a registered controller (a TOML string; the registry is
    /// [`exompc::scenario::controllers`](crate::scenario::controllers)).
    Controller,
    /// A name (a TOML string): non-empty, at most this many characters, no commas, quotes or
    /// control characters, no leading or trailing space, unique among its tables.
    Name(usize),
}

impl Allowed {
    /// The allowed values in words, in the style of [`super::ConfigError`]'s `allowed`:
    /// `finite, in (0, robot.thigh.length_m]`, `integer in 1..=200`, `"hold" or "predict"`.
    pub fn describe(&self) -> String {
        match *self {
            Allowed::Table => "a table".into(),
            Allowed::Tables => "any number of tables".into(),
            Allowed::Real { lo: None, hi: None } => "finite".into(),
            Allowed::Real {
                lo: Some(lo),
                hi: None,
            } => format!(
                "finite, {} {}",
                if lo.inclusive { ">=" } else { ">" },
                lo.at
            ),
            Allowed::Real {
                lo: None,
                hi: Some(hi),
            } => format!(
                "finite, {} {}",
                if hi.inclusive { "<=" } else { "<" },
                hi.at
            ),
            Allowed::Real {
                lo: Some(lo),
                hi: Some(hi),
            } => format!(
                "finite, in {}{}, {}{}",
                if lo.inclusive { '[' } else { '(' },
                lo.at,
                hi.at,
                if hi.inclusive { ']' } else { ')' }
            ),
            Allowed::Int { lo, hi } => format!("integer in {lo}..={hi}"),
            Allowed::RealOrWord { lo, word } => format!("finite, >= {lo}, or \"{word}\""),
            Allowed::List {
                min_len,
                max_len,
                lo,
                hi,
            } => format!("{min_len} to {max_len} entries, each finite, in [{lo}, {hi}]"),
            Allowed::Choice(words) => {
                let quoted: Vec<String> = words.iter().map(|w| format!("\"{w}\"")).collect();
                match quoted.split_last() {
                    Some((last, [])) => last.clone(),
                    Some((last, rest)) => format!("{} or {last}", rest.join(", ")),
                    None => String::new(),
                }
            }
            Allowed::Controller => {
                "the name of a registered controller".into()
            }
            Allowed::Bool => "true or false".into(),
            Allowed::Path => "a file path (relative to the config file's folder)".into(),
            Allowed::Name(n) => format!(
                "a unique name of 1 to {n} characters, without commas, quotes or leading/trailing spaces"
            ),
        }
    }

    /// Other keys this range depends on (cross-field rules).
    pub fn depends_on(&self) -> Vec<&'static str> {
        let key = |l: Limit| match l {
            Limit::Key(k) | Limit::InverseLen(k) => Some(k),
            Limit::Num(_) => None,
        };
        match *self {
            Allowed::Real { lo, hi } => [lo, hi]
                .into_iter()
                .flatten()
                .filter_map(|e| key(e.at))
                .collect(),
            Allowed::Int { hi, .. } => key(hi).into_iter().collect(),
            _ => Vec::new(),
        }
    }
}

/// The explanation of one key or table of a scenario file.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyDoc {
    /// Dotted path: `trajectory.hip_amplitude`, or a table: `robot.thigh`. Keys of the
    /// `[[faults.events]]` tables are `faults.events.<key>`.
    pub path: &'static str,
    /// Unit (`m`, `N·m`, `-` for a pure number, empty for words, switches and tables).
    pub unit: &'static str,
    /// What it is, in one line.
    pub meaning: &'static str,
    /// Allowed values.
    pub allowed: Allowed,
    /// Where it comes from: `docs/MODEL.md §3`, `paper Table 1`, `docs/RELIABILITY.md §2`.
    pub source: &'static str,
}

impl KeyDoc {
    /// True for a table (`[robot.thigh]`) or an array of tables (`[[faults.events]]`).
    pub fn is_table(&self) -> bool {
        matches!(self.allowed, Allowed::Table | Allowed::Tables)
    }

    /// One comment line: `[m] Thigh strap distance from the hip. Allowed: finite, in (0,
    /// robot.thigh.length_m]. (docs/MODEL.md §4)`.
    pub fn comment(&self) -> String {
        let mut s = String::new();
        if !self.unit.is_empty() {
            let _ = write!(s, "[{}] ", self.unit);
        }
        s += self.meaning;
        if !self.is_table() {
            let _ = write!(s, " Allowed: {}.", self.allowed.describe());
        }
        if !self.source.is_empty() {
            let _ = write!(s, " ({})", self.source);
        }
        s
    }
}

/// The explanation of a key or table by its dotted path (`faults.events[0].kind` and
/// `faults.events.kind` both find the fault-event key).
pub fn explain(path: &str) -> Option<&'static KeyDoc> {
    let mut p = String::with_capacity(path.len());
    let mut skip = false;
    for c in path.trim().chars() {
        match c {
            '[' => skip = true,
            ']' => skip = false,
            _ if !skip => p.push(c),
            _ => {}
        }
    }
    KEYS.iter().find(|k| k.path == p)
}

const fn open(v: f64) -> Option<End> {
    Some(End {
        at: Limit::Num(v),
        inclusive: false,
    })
}
const fn closed(v: f64) -> Option<End> {
    Some(End {
        at: Limit::Num(v),
        inclusive: true,
    })
}
const fn key_closed(k: &'static str) -> Option<End> {
    Some(End {
        at: Limit::Key(k),
        inclusive: true,
    })
}
const ANY: Allowed = Allowed::Real { lo: None, hi: None };
const POS: Allowed = Allowed::Real {
    lo: open(0.0),
    hi: None,
};
const NONNEG: Allowed = Allowed::Real {
    lo: closed(0.0),
    hi: None,
};
const AUTO: Allowed = Allowed::RealOrWord {
    lo: 0.0,
    word: "auto",
};
const FRACTION: Allowed = Allowed::Real {
    lo: open(0.0),
    hi: closed(1.0),
};
const fn real(lo: Option<End>, hi: Option<End>) -> Allowed {
    Allowed::Real { lo, hi }
}
const fn int(lo: u64, hi: u64) -> Allowed {
    Allowed::Int {
        lo,
        hi: Limit::Num(hi as f64),
    }
}
const fn k(
    path: &'static str,
    unit: &'static str,
    allowed: Allowed,
    source: &'static str,
    meaning: &'static str,
) -> KeyDoc {
    KeyDoc {
        path,
        unit,
        meaning,
        allowed,
        source,
    }
}
const fn table(path: &'static str, source: &'static str, meaning: &'static str) -> KeyDoc {
    k(path, "", Allowed::Table, source, meaning)
}

const M2: &str = "docs/MODEL.md §2";
const M3: &str = "docs/MODEL.md §3";
const M4: &str = "docs/MODEL.md §4";
const M5: &str = "docs/MODEL.md §5";
const M6: &str = "docs/MODEL.md §6";
const M7: &str = "docs/MODEL.md §7";
const M8: &str = "docs/MODEL.md §8";
const M8X: &str = "docs/MODEL.md §8, What exompc adds";
const ROB: &str = "docs/ROBUSTNESS-controller.md, Settings";
const REL1: &str = "docs/RELIABILITY.md §1";
const REL2: &str = "docs/RELIABILITY.md §2";
const FALLBACK: &str = "docs/ROBUSTNESS.md §5";
const PERF: &str = "docs/PERFORMANCE.md";
const M8S: &str = "docs/SCENARIOS.md, docs/MODEL.md §8";

/// Every key and table of a scenario file, in file order.
pub const KEYS: &[KeyDoc] = &[
    // [human]
    table("human", M2, "The human leg model and its \"brain\" (paper eq. 2)."),
    k("human.height_m", "m", POS, M2, "Body height H; the segment lengths are fractions of it."),
    k("human.body_mass_kg", "kg", POS, M2, "Body mass m_b of the brain model, and the plant's at t = 0."),
    k("human.final_body_mass_kg", "kg", POS, M2, "Plant body mass at the end of the 2-DOF run (linear ramp, uncertainty.human_mass_ramp)."),
    k("human.kp", "1/s²", POS, M2, "Brain PD stiffness Kp on the joint-angle error."),
    k("human.kd", "1/s", POS, M2, "Brain PD damping Kd on the joint-velocity error."),
    table("human.thigh", M2, "Winter's anthropometric fractions of the thigh; a partial table keeps the other thigh defaults."),
    k("human.thigh.mass_fraction", "-", FRACTION, M2, "Thigh mass as a fraction of body mass."),
    k("human.thigh.length_fraction", "-", FRACTION, M2, "Thigh length as a fraction of body height."),
    k("human.thigh.com_fraction", "-", FRACTION, M2, "Thigh COM distance from the hip as a fraction of its length."),
    k("human.thigh.gyration_fraction", "-", FRACTION, M2, "Thigh radius of gyration about its COM as a fraction of its length."),
    table("human.shank", M2, "Winter's anthropometric fractions of the shank + foot; a partial table keeps the other shank defaults."),
    k("human.shank.mass_fraction", "-", FRACTION, M2, "Shank + foot mass as a fraction of body mass."),
    k("human.shank.length_fraction", "-", FRACTION, M2, "Shank length as a fraction of body height."),
    k("human.shank.com_fraction", "-", FRACTION, M2, "Shank COM distance from the knee as a fraction of its length."),
    k("human.shank.gyration_fraction", "-", FRACTION, M2, "Shank radius of gyration about its COM as a fraction of its length."),
    // [robot]
    table("robot", M3, "The exoskeleton (paper eq. 1, Table 1)."),
    k("robot.viscous_friction", "N·m·s", NONNEG, "docs/MODEL.md §3, paper Table 1", "Viscous friction kf1 per joint."),
    k("robot.coulomb_friction", "N·m", NONNEG, "docs/MODEL.md §3, paper Table 1", "Coulomb friction kf2 per joint."),
    k("robot.coulomb_smoothing", "rad/s", POS, M3, "Width w of the smooth Coulomb term kf2·tanh(qd/w) of the prediction models (the plant uses sign)."),
    k("robot.payload_position_m", "m", real(closed(0.0), key_closed("robot.shank.length_m")), M3, "Payload point-mass position on the shank, measured from the knee."),
    table("robot.thigh", M3, "Robot thigh link; a partial table keeps the other thigh defaults."),
    k("robot.thigh.length_m", "m", POS, M3, "Thigh link length l1 (hip to knee)."),
    k("robot.thigh.mass_kg", "kg", POS, M3, "Thigh link mass m1."),
    k("robot.thigh.com_m", "m", real(closed(0.0), key_closed("robot.thigh.length_m")), M3, "Thigh COM distance c1 from the hip along the link."),
    k("robot.thigh.inertia_kgm2", "kg·m²", POS, M3, "Thigh inertia I1 about its COM."),
    table("robot.shank", M3, "Robot shank link; a partial table keeps the other shank defaults."),
    k("robot.shank.length_m", "m", POS, M3, "Shank link length l2 (knee to end)."),
    k("robot.shank.mass_kg", "kg", POS, M3, "Shank link mass m2 (without payload)."),
    k("robot.shank.com_m", "m", real(closed(0.0), key_closed("robot.shank.length_m")), M3, "Shank COM distance c2 from the knee along the link."),
    k("robot.shank.inertia_kgm2", "kg·m²", POS, M3, "Shank inertia I2 about its COM."),
    // [straps]
    table("straps", M4, "Spring-damper straps between human and robot (paper eqs. 3-4)."),
    k("straps.ls1_m", "m", real(open(0.0), key_closed("robot.thigh.length_m")), M4, "Thigh strap distance Ls1 from the hip."),
    k("straps.ls2_m", "m", real(open(0.0), key_closed("robot.shank.length_m")), M4, "Shank strap distance Ls2 from the knee."),
    k("straps.stiffness", "N/m", POS, M4, "Strap stiffness ks."),
    k("straps.damping", "N·s/m", NONNEG, M4, "Strap damping cs."),
    // [uncertainty]
    table("uncertainty", M5, "Plant uncertainties and sensor imperfections (paper §4.1)."),
    k("uncertainty.payload_kg", "kg", real(closed(0.0), closed(MAX_PAYLOAD_KG)), M5, "True payload m_p on the robot shank, unknown to the controller."),
    k("uncertainty.mass_perturbation", "", Allowed::Bool, M5, "Add m_dis(t) = 0.05 sin(t) + 0.01 sin(100 t + π/4) kg to each robot link."),
    k("uncertainty.disturbance", "", Allowed::Bool, M5, "Add the joint disturbance D(t) = 0.1 sin(t) + 0.05 sin(100 t + π/2) N·m."),
    k("uncertainty.human_mass_ramp", "", Allowed::Bool, M2, "Ramp the plant's body mass from human.body_mass_kg to human.final_body_mass_kg over the 2-DOF run."),
    k("uncertainty.velocity_noise", "rad/s", NONNEG, M5, "Amplitude a of the velocity measurement noise a·sin(w t)."),
    k("uncertainty.force_noise", "N", NONNEG, M5, "Amplitude of the strap-force measurement noise."),
    k("uncertainty.noise_frequency", "rad/s", NONNEG, M5, "Angular frequency w of the measurement noise."),
    k("uncertainty.filter_window", "samples", int(1, 100), M5, "Moving-average window on the measured velocities and forces."),
    // [trajectory]
    table("trajectory", M6, "The human's desired motion."),
    k("trajectory.kind", "", Allowed::Choice(&["parametric", "sine", "recorded"]), M6, "The human's desired motion: the paper's parametric swing (also spelled sine), or joint angles recorded in a CSV file (trajectory.file)."),
    k("trajectory.file", "", Allowed::Path, "README, Your own gait data; docs/MODEL.md §6", "CSV of time and joint angles (t_s,hip_rad,knee_rad or _deg columns) replayed when kind = \"recorded\", relative to the config file's folder; optional."),
    k("trajectory.base_frequency_hz", "Hz", POS, M6, "Mean gait frequency of the 2-DOF swing."),
    k("trajectory.frequency_swing_hz", "Hz", real(closed(0.0), Some(End { at: Limit::Key("trajectory.base_frequency_hz"), inclusive: false })), M6, "Amplitude of the gait-frequency variation."),
    k("trajectory.frequency_period_s", "s", POS, M6, "Period of the gait-frequency variation."),
    k("trajectory.hip_offset", "rad", ANY, M6, "Hip angle offset (the centre of the hip swing)."),
    k("trajectory.hip_amplitude", "rad", NONNEG, M6, "Mean hip swing amplitude a_h."),
    k("trajectory.hip_amplitude_swing", "rad", NONNEG, M6, "Amplitude of the hip-amplitude variation."),
    k("trajectory.hip_amplitude_period_s", "s", POS, M6, "Period of the hip-amplitude variation."),
    k("trajectory.knee_amplitude", "rad", NONNEG, M6, "Mean knee flexion amplitude a_k."),
    k("trajectory.knee_amplitude_swing", "rad", NONNEG, M6, "Amplitude of the knee-amplitude variation."),
    k("trajectory.knee_amplitude_period_s", "s", POS, M6, "Period of the knee-amplitude variation."),
    k("trajectory.knee_phase", "rad", ANY, M6, "Phase lag of the knee behind the hip (π/3)."),
    k("trajectory.one_dof_amplitude", "rad", NONNEG, M6, "Knee amplitude of the 1-DOF run: q_d2 = -a (1 - cos(2π f t))."),
    k("trajectory.one_dof_frequency_hz", "Hz", POS, M6, "Knee frequency f of the 1-DOF run."),
    // [timing]
    table("timing", M7, "Control period, integration steps and run lengths."),
    k("timing.dt", "s", real(open(0.0), closed(1.0)), M7, "Control period dt; each torque is held over one period."),
    k("timing.plant_substeps", "steps", int(1, 1000), M7, "Plant RK4 steps per control period (10: 1 ms steps)."),
    k("timing.prediction_substeps", "steps", int(1, 1000), M7, "Prediction-model (and EKF) RK4 steps per control period."),
    k("timing.duration_2dof_s", "s", real(key_closed("timing.dt"), closed(1e6)), M7, DURATION_NOTE_2),
    k("timing.duration_1dof_s", "s", real(key_closed("timing.dt"), closed(1e6)), M7, DURATION_NOTE_1),
    // [controller]
    table("controller", M8, "Human-intent estimation and the NMPC (paper eqs. 5-9, Table 1)."),
    k("controller.kind", "", Allowed::Controller, M8X, "Controller used by simulate, by its name in the controller registry (the built-in ones: baseline PD, plain NMPC on the 0 kg model, multi-stage robust NMPC)."),
    k("controller.k1", "rad/N", AUTO, "docs/MODEL.md §8, paper eq. 5", "Intent gain K1: estimated human angle q_R + K1 F; \"auto\" = 4.6875 rad/m / straps.stiffness (0.005 at the default straps)."),
    k("controller.k2", "rad/(N·s)", AUTO, "docs/MODEL.md §8, paper eq. 6", "Intent gain K2: estimated human velocity qd_R + K2 F; \"auto\" = 46.875 rad/(m·s) / straps.stiffness (0.05 at the default straps)."),
    k("controller.np", "steps", int(1, 200), "docs/MODEL.md §8, paper Table 1", "Prediction horizon Np."),
    k("controller.nc", "steps", Allowed::Int { lo: 1, hi: Limit::Key("controller.np") }, "docs/MODEL.md §8, paper Table 1", "Control horizon Nc (torque increments optimised; held after)."),
    k("controller.r_d", "s²", NONNEG, "docs/MODEL.md §8, paper eq. 7", "Weight of the velocity-tracking error in the cost."),
    k("controller.r_t", "1/(N·m)²", POS, "docs/MODEL.md §8, paper eq. 7", "Weight of the torque increments in the cost (1e-5; the paper's 1e-6 limit-cycles, see the note)."),
    k("controller.torque_max", "N·m", POS, "docs/MODEL.md §8, paper eq. 8", "Torque bound |T| per joint, a hard guarantee on every output."),
    k("controller.torque_rate_max", "N·m/s", POS, "docs/MODEL.md §8, paper eq. 9", "Torque-rate bound; the per-step bound on |dT| is torque_rate_max·dt."),
    k("controller.interaction", "", Allowed::Choice(&["predict", "hold"]), M8, "Strap torque over the horizon: predicted from the intent estimate, or the measured one held."),
    k("controller.method", "", Allowed::Choice(&["paper", "robust"]), ROB, "Multi-stage method: the paper's exactly, or with the [controller.robust] extensions."),
    table("controller.sqp", M8, "SQP solver limits (paper §3.1)."),
    k("controller.sqp.max_iterations", "iterations", int(1, 1000), M8, "Most SQP iterations per solve."),
    k("controller.sqp.kkt_tolerance", "-", real(closed(0.0), closed(1.0)), M8, "KKT residual at which a solve counts as converged (0: never, every solve runs to a limit)."),
    k("controller.sqp.max_time_us", "µs", int(0, 10_000_000), M8, "Optional wall-clock budget per solve (0: stop after the first iteration); absent (the default) = no budget."),
    k("controller.sqp.rti", "", Allowed::Bool, PERF, "Real-time iteration: one linearisation and one QP per control period from the shifted previous solution, instead of iterating to the KKT tolerance."),
    k("controller.sqp.hessian", "", Allowed::Choice(&["auto", "gauss_newton", "structured_secant", "exact"]), PERF, "Hessian model of the QP subproblems: auto (the QP back-end's own: structured_secant on dense, gauss_newton on structured), Gauss-Newton, Gauss-Newton plus a structured secant term (dense back-end only), or the exact Hessian (shifted by mu*I, IPOPT's inertia correction, when not positive definite; the coupled tree uses Gauss-Newton). The run summary's solver.hessian names the model run."),
    k("controller.sqp.qp", "", Allowed::Choice(&["dense", "structured", "auto"]), PERF, "QP solver: condensed dense, Riccati over the stages (coupled: block-arrowhead scenario tree), or auto (structured when joints·nc >= 16; coupled: when the tree has >= 16 decision variables; auto chooses the back-end only, never one that runs another Hessian than hessian asks for). The run summary's solver.qp names the back-end chosen."),
    table("controller.pd", M8X, "Gains of the baseline PD controller (controller.kind = \"pd\")."),
    k("controller.pd.kp", "N·m/rad", POS, M8X, "PD proportional gain on the estimated human angle error."),
    k("controller.pd.kd", "N·m·s/rad", POS, M8X, "PD derivative gain on the estimated human velocity error."),
    table("controller.robust", ROB, "Extensions of method = \"robust\" (ignored for \"paper\"); the detectors' thresholds, the disturbance bank and the inertia gate are fixed constants (control::RobustTuning), and a file setting one of their former keys is rejected naming it."),
    k("controller.robust.filter_aware", "", Allowed::Choice(&["off", "on_oscillation", "always"]), ROB, "When the filter-aware mode (the EKF bank's lag-free velocity and the Smith-predicted strap force instead of the filtered ones) is used: never (the paper's estimate), from the first interaction oscillation the detectors or the inertia gate see, or from the first step (tracks less tightly where the paper's method is stable)."),
    k("controller.robust.human_bandwidth_hz", "Hz", POS, ROB, "Bandwidth of the human's motion in the Smith predictor and the strap observer: the human's acceleration is the robot's low-passed at it; raise it for faster movements than walking (follows more of the robot's acceleration and its noise)."),
    k("controller.robust.release_s", "s", real(closed(0.0), closed(1e6)), ROB, "Return to the paper's estimate after this long without oscillation; 0 = stay engaged."),
    k("controller.robust.weight_smoothing_s", "s", real(closed(0.0), closed(10.0)), ROB, "Time constant of the low-pass on the scenario probabilities that weight the MS-NMPC's costs, started once one scenario first holds more than half of the probability; longer = smoother torque where the posteriors chatter, slower to follow a real payload change; 0 = the probabilities as they are."),
    k("controller.robust.intent_estimate", "", Allowed::Choice(&["strap_observer", "paper"]), ROB, "Human-intent estimate of the robust method: the strap model inverted as an observer of the stretch and its rate, moved over the sensor filter's lag, with the NMPC started from the EKF bank's velocity; or the paper's eqs. 5-6."),
    k("controller.robust.observer_velocity_gain", "1/s", real(closed(0.0), closed(1000.0)), ROB, "With intent_estimate = \"strap_observer\": gain of the human-robot angle error in the reference velocity, qd_ref = q̂d_H + kv (q̂_H - q_R); higher closes an angle gap to the person faster, with stiffer interaction."),
    k("controller.robust.velocity_tracking", "", Allowed::Choice(&["strap", "joint"]), ROB, "Where the NMPC's velocity residual is measured: at the straps (each strap's stretch rate in its link's angle units, L = diag(J)^-1 J), so a hip on its torque limit does not load the shank strap too; or in joint space (the paper's eq. 7)."),
    k("controller.robust.intent_gains", "", Allowed::Choice(&["strap_model", "configured"]), ROB, "Intent gains of the robust method: controller.k1/k2 scaled by 937.5 N/m / straps.stiffness (equal at the default straps), or as configured."),
    // [multistage]
    table("multistage", M8, "Scenario tree and probabilities of the multi-stage NMPC (paper eqs. 10-13)."),
    k("multistage.payloads_kg", "kg", Allowed::List { min_len: 1, max_len: MAX_SCENARIOS, lo: 0.0, hi: MAX_PAYLOAD_KG }, M8, "Payload of each scenario (one EKF and one NMPC each)."),
    k("multistage.c1", "-", POS, "docs/MODEL.md §8, paper eq. 10", "Convergence constant c1 of the probability update."),
    k("multistage.probability_floor", "-", real(open(0.0), Some(End { at: Limit::InverseLen("multistage.payloads_kg"), inclusive: false })), "docs/MODEL.md §8, paper eq. 11", "Floor of each scenario probability before renormalisation."),
    k("multistage.formulation", "", Allowed::Choice(&["decoupled", "coupled"]), M8X, "One NMPC per scenario blended by probability (eq. 13), or one coupled problem (eq. 12)."),
    k("multistage.robust_horizon", "steps", Allowed::Int { lo: 1, hi: Limit::Key("controller.nc") }, M8X, "Leading control moves shared by all scenarios (coupled formulation)."),
    k("multistage.parallel", "", Allowed::Bool, PERF, "Solve the scenarios in parallel threads."),
    k("multistage.innovation", "", Allowed::Choice(&["standard", "paper"]), M8X, "EKF innovation used for the probabilities: the standard one or the paper's."),
    table("multistage.scenarios", M8S, "Named scenarios, each a [[multistage.scenarios]] table overriding parts of [robot] and [straps]; they replace payloads_kg. None by default."),
    k("multistage.scenarios.name", "", Allowed::Name(scenarios::MAX_NAME_LEN), M8S, "Name of the scenario in trace columns, legends and summaries."),
    k("multistage.scenarios.payload_kg", "kg", real(closed(0.0), Some(End { at: Limit::Num(MAX_PAYLOAD_KG), inclusive: true })), M8S, "Payload the scenario's robot model carries at robot.payload_position_m; absent: 0."),
    table("multistage.scenarios.robot", M8S, "Override of [robot] in this scenario's model; absent keys keep the base values."),
    k("multistage.scenarios.robot.viscous_friction", "N·m·s", NONNEG, M8S, "Viscous friction kf1 of this scenario's model."),
    k("multistage.scenarios.robot.coulomb_friction", "N·m", NONNEG, M8S, "Coulomb friction kf2 of this scenario's model."),
    k("multistage.scenarios.robot.coulomb_smoothing", "rad/s", POS, M8S, "Coulomb smoothing width of this scenario's model."),
    k("multistage.scenarios.robot.payload_position_m", "m", real(closed(0.0), key_closed("multistage.scenarios.robot.shank.length_m")), M8S, "Payload position on the shank in this scenario's model."),
    table("multistage.scenarios.robot.thigh", M8S, "Override of [robot.thigh] in this scenario's model."),
    k("multistage.scenarios.robot.thigh.length_m", "m", POS, M8S, "Thigh link length of this scenario's model."),
    k("multistage.scenarios.robot.thigh.mass_kg", "kg", POS, M8S, "Thigh link mass of this scenario's model."),
    k("multistage.scenarios.robot.thigh.com_m", "m", real(closed(0.0), key_closed("multistage.scenarios.robot.thigh.length_m")), M8S, "Thigh COM distance from the hip in this scenario's model."),
    k("multistage.scenarios.robot.thigh.inertia_kgm2", "kg·m²", POS, M8S, "Thigh inertia about its COM in this scenario's model."),
    table("multistage.scenarios.robot.shank", M8S, "Override of [robot.shank] in this scenario's model."),
    k("multistage.scenarios.robot.shank.length_m", "m", POS, M8S, "Shank link length of this scenario's model."),
    k("multistage.scenarios.robot.shank.mass_kg", "kg", POS, M8S, "Shank link mass of this scenario's model."),
    k("multistage.scenarios.robot.shank.com_m", "m", real(closed(0.0), key_closed("multistage.scenarios.robot.shank.length_m")), M8S, "Shank COM distance from the knee in this scenario's model."),
    k("multistage.scenarios.robot.shank.inertia_kgm2", "kg·m²", POS, M8S, "Shank inertia about its COM in this scenario's model."),
    table("multistage.scenarios.straps", M8S, "Override of [straps] in this scenario's model."),
    k("multistage.scenarios.straps.ls1_m", "m", real(open(0.0), key_closed("multistage.scenarios.robot.thigh.length_m")), M8S, "Thigh strap distance from the hip in this scenario's model."),
    k("multistage.scenarios.straps.ls2_m", "m", real(open(0.0), key_closed("multistage.scenarios.robot.shank.length_m")), M8S, "Shank strap distance from the knee in this scenario's model."),
    k("multistage.scenarios.straps.stiffness", "N/m", POS, M8S, "Strap stiffness of this scenario's model."),
    k("multistage.scenarios.straps.damping", "N·s/m", NONNEG, M8S, "Strap damping of this scenario's model."),
    // [ekf]
    table("ekf", M8, "Covariances of each scenario's EKF on [q, qd, d]."),
    k("ekf.q_angle", "rad²", POS, M8, "Process noise variance of each joint angle per step."),
    k("ekf.q_velocity", "(rad/s)²", POS, M8, "Process noise variance of each joint velocity per step."),
    k("ekf.q_disturbance", "(N·m)²", POS, M8, "Random-walk variance of each lumped disturbance per step."),
    k("ekf.r_angle", "rad²", POS, M8, "Measurement noise variance of each angle."),
    k("ekf.r_velocity", "(rad/s)²", POS, M8, "Measurement noise variance of each filtered velocity."),
    k("ekf.p0_angle", "rad²", POS, M8, "Initial covariance of each angle."),
    k("ekf.p0_velocity", "(rad/s)²", POS, M8, "Initial covariance of each velocity."),
    k("ekf.p0_disturbance", "(N·m)²", POS, M8, "Initial covariance of each disturbance."),
    // [faults]
    table("faults", REL1, "Scripted sensor faults and the force sensor's range."),
    k("faults.events", "", Allowed::Tables, REL1, "Fault events, each a [[faults.events]] table; none by default."),
    k("faults.events.kind", "", Allowed::Choice(&FaultKind::NAMES), REL1, "Fault kind."),
    k("faults.events.channel", "", Allowed::Choice(&Channel::NAMES), REL1, "Affected channel: joint angle, joint velocity or strap force of joint 1 (hip) or 2 (knee)."),
    k("faults.events.start_s", "s", NONNEG, REL1, "Start time of the fault."),
    k("faults.events.duration_s", "s", NONNEG, REL1, "Duration of the fault."),
    k("faults.events.magnitude", "rad, rad/s or N", ANY, REL1, "Added to the reading by a spike (the channel's unit); optional, default 0."),
    k("faults.saturation_n", "N", POS, M5, "Force sensor range: raw strap-force samples are clipped to ±saturation_n."),
    // [monitors]
    table("monitors", REL2, "Runtime safety monitors of the supervisor."),
    k("monitors.tracking_error_max_rad", "rad", POS, REL2, "Trip when the human-robot angle error estimated from the strap forces exceeds this."),
    k("monitors.force_max_n", "N", POS, REL2, "Trip when a measured strap force exceeds this."),
    k("monitors.sensor_timeout_s", "s", POS, REL2, "Persistent-fault limit: an encoder angle rejected (non-finite, out of range, frozen or outside its innovation gate) for longer than this, or a velocity whose angle is measured or a strap force for 4 times as long, or an angle or velocity of a joint whose angle and velocity are both rejected for 2 times as long, ends in the protective stop (torque ramped to zero at 100 N·m/s, within the rate limit, held until every channel is good again); shorter faults are ridden through on the channel's estimate."),
    k("monitors.response", "", Allowed::Choice(&["hold", "ramp_to_zero", "fallback"]), REL2, "What a tripped monitor does: hold the last safe torque, ramp to zero at 100 N·m/s (within the rate limit), or hand over to the transparent fallback controller (gravity, friction, inertia and payload compensated); hold and ramp_to_zero hand over to the fallback when they have had the torque for 0.02 s and the trip's cause is present."),
    k("monitors.oscillation_force_rms_n", "N", POS, REL2, "Oscillation monitor: trip when a strap force's RMS above the cut-off exceeds this."),
    k("monitors.oscillation_torque_rms_nm", "N·m", POS, REL2, "Oscillation monitor: the same on the commanded joint torques."),
    k("monitors.oscillation_cutoff_hz", "Hz", POS, REL2, "Oscillation monitor high-pass cut-off (taken just below Nyquist if above it)."),
    k("monitors.oscillation_window_s", "s", real(open(0.0), closed(10.0)), REL2, "Oscillation monitor sliding window."),
    k("monitors.oscillation_cutoff_gait_ratio", "-", real(closed(0.0), closed(20.0)), REL2, "Gait-following cut-off: the oscillation monitors high-pass at max(oscillation_cutoff_hz, this × the gait frequency estimated from the human's joint angles, at most 2 Hz), so a fast gait's own torque is not an oscillation; 0: fixed cut-off."),
    k("monitors.oscillation_clear_s", "s", real(closed(0.0), closed(1e6)), REL2, "A tripped oscillation monitor clears after its condition has been absent this long."),
    k("monitors.latch_trips", "trips", int(0, 1000), REL2, "Latch after this many handovers (a tracking-error, strap-force or oscillation monitor taking the torque from the controller) within latch_window_s: the response then keeps the torque until an operator's reset; 0: never latch."),
    k("monitors.latch_window_s", "s", real(open(0.0), closed(1e6)), REL2, "The window of latch_trips."),
    k("monitors.encoder_step_rad", "rad", real(closed(0.0), closed(0.01)), REL2, "The encoders' angle step: a quantised angle repeats while its joint moves less than a step per period, so an angle repeated bit for bit counts as frozen only while the joint moves faster than max(0.05 rad/s, 2 × this / dt), and on its first repeat only where the angles' extrapolation moves it by more than 4 × this; 0: 0.05 rad/s alone (exact angles; the T-Motor AK's 16-bit position). exompc run with CiA 402 drives takes at least one position increment at the joint."),
    table("monitors.fallback", FALLBACK, "The transparent fallback controller of response = \"fallback\" (and what hold and ramp_to_zero hand over to when the trip's cause is present after 0.02 s): the robot's inverse dynamics along the predicted human motion."),
    k("monitors.fallback.inertia_share", "-", real(closed(0.0), closed(1.0)), FALLBACK, "Share of the robot's inertia compensated along the predicted human acceleration."),
    k("monitors.fallback.acceleration_cutoff_hz", "Hz", POS, FALLBACK, "Low-pass cut-off of the encoder acceleration in the robot's velocity estimate (Coriolis, friction)."),
    k("monitors.fallback.estimate_memory_s", "s", POS, FALLBACK, "Memory of the payload estimate's exponentially weighted least squares."),
    k("monitors.fallback.max_payload_kg", "kg", real(closed(0.0), closed(20.0)), FALLBACK, "The payload estimate is kept in [0, this]."),
    k("monitors.fallback.human_window", "samples", int(4, 100), FALLBACK, "Human-angle estimates in the cubic least-squares fit that predicts the human's acceleration."),
    k("monitors.fallback.human_prediction_s", "s", real(closed(0.0), closed(0.1)), FALLBACK, "How far ahead of the newest human-angle estimate (one period old) the fit is evaluated."),
];

/// Meaning of the run-length keys (they also allow at most [`MAX_CONTROL_STEPS`] steps).
const DURATION_NOTE_2: &str =
    "Length of the 2-DOF run (also at most 100000000 control steps, duration/dt).";
const DURATION_NOTE_1: &str =
    "Length of the 1-DOF run (also at most 100000000 control steps, duration/dt).";
const _: () = assert!(MAX_CONTROL_STEPS == 100_000_000, "update DURATION_NOTE_*");

/// The error for a key the scenario file no longer has, by its dotted path
/// (`controller.robust.disturbance_lead`, [`crate::control::REMOVED_ROBUST_KEYS`]); `None`
/// for any other path. A file or `set` naming such a key is rejected with it, never ignored.
pub fn removed_key(path: &str) -> Option<String> {
    let key = path.strip_prefix("controller.robust.")?;
    crate::control::REMOVED_ROBUST_KEYS
        .contains(&key)
        .then(|| crate::control::removed_robust_key(key))
}
