//! `simulate`, `run_many` and the `Simulator` (plant + sensors) of the closed loop.

use crate::convert::{array, trace_key as key, trace_vector_columns as vector_columns, vector};
use crate::guard::{catch, interruptible, CancelToken, Outcome};
use crate::memory;
use crate::scenario::PyScenario;
use crate::{ConfigError, RunError};
use exompc::config::Experiment;
use exompc::scenario::{plant_params, run_experiment, uncertainty, Dof, OneDof, TwoDof};
use exompc::sim::trace::{self, Field};
use exompc::sim::{Plant, Recorder, Sensors, StepRecord, StopWhen, Summary, Trajectory};
use exompc_study::io::{parse_value, set_key};
use numpy::{PyArray1, PyArrayMethods};
use pyo3::exceptions::PyMemoryError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rayon::prelude::*;

/// The trace of one run as flat columns (row-major `steps × width`), keyed as the library's
/// column table says (the `python` keys of [`trace::TRACE_COLUMNS`]).
struct Columns {
    n: usize,
    scenarios: usize,
    t: Vec<f64>,
    /// One per [`vector_columns`] entry.
    vec: Vec<Vec<f64>>,
    probabilities: Vec<f64>,
    disturbances: Vec<f64>,
    status: Vec<u8>,
    iterations: Vec<u32>,
    step_time_us: Vec<f64>,
    within_limits: Vec<bool>,
}

impl<const N: usize> Recorder<N> for Columns {
    fn record(&mut self, r: &StepRecord<'_, N>) -> std::io::Result<()> {
        self.n = N;
        self.t.push(r.t);
        for (c, v) in vector_columns().zip(&mut self.vec) {
            v.extend((0..N).map(|j| trace::value(r, c.field, j)));
        }
        if let Some(p) = r.probabilities {
            self.scenarios = p.len();
            self.probabilities.extend_from_slice(p);
        }
        if let Some(d) = r.disturbances {
            for x in d {
                self.disturbances.extend_from_slice(x.as_slice());
            }
        }
        self.status.push(r.status.code());
        self.iterations.push(r.iterations);
        self.step_time_us.push(r.step_time_us);
        self.within_limits.push(r.within_limits);
        Ok(())
    }
}

impl Columns {
    /// Empty columns with room for `steps` rows of `n` joints and `scenarios` scenarios,
    /// reserved up front (a `MemoryError` if the system refuses, never an abort).
    fn with_capacity(steps: usize, n: usize, scenarios: usize) -> PyResult<Self> {
        let oom = |_| PyMemoryError::new_err(format!("cannot allocate the trace of {steps} steps"));
        let mut c = Columns {
            n,
            scenarios: 0,
            t: Vec::new(),
            vec: vector_columns().map(|_| Vec::new()).collect(),
            probabilities: Vec::new(),
            disturbances: Vec::new(),
            status: Vec::new(),
            iterations: Vec::new(),
            step_time_us: Vec::new(),
            within_limits: Vec::new(),
        };
        c.t.try_reserve_exact(steps).map_err(oom)?;
        for v in &mut c.vec {
            v.try_reserve_exact(steps.saturating_mul(n)).map_err(oom)?;
        }
        c.probabilities
            .try_reserve_exact(steps.saturating_mul(scenarios))
            .map_err(oom)?;
        c.disturbances
            .try_reserve_exact(steps.saturating_mul(scenarios).saturating_mul(n))
            .map_err(oom)?;
        c.status.try_reserve_exact(steps).map_err(oom)?;
        c.iterations.try_reserve_exact(steps).map_err(oom)?;
        c.step_time_us.try_reserve_exact(steps).map_err(oom)?;
        c.within_limits.try_reserve_exact(steps).map_err(oom)?;
        Ok(c)
    }

    fn into_dict(self, py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
        let d = PyDict::new(py);
        let steps = self.t.len();
        d.set_item(key(Field::Time), PyArray1::from_vec(py, self.t))?;
        for (c, v) in vector_columns().zip(self.vec) {
            let name = c.python.unwrap_or("?");
            d.set_item(name, PyArray1::from_vec(py, v).reshape([steps, self.n])?)?;
        }
        if self.scenarios > 0 {
            d.set_item(
                key(Field::Probability),
                PyArray1::from_vec(py, self.probabilities).reshape([steps, self.scenarios])?,
            )?;
            d.set_item(
                key(Field::Disturbance),
                PyArray1::from_vec(py, self.disturbances).reshape([
                    steps,
                    self.scenarios,
                    self.n,
                ])?,
            )?;
        }
        d.set_item(key(Field::Status), PyArray1::from_vec(py, self.status))?;
        d.set_item(
            key(Field::Iterations),
            PyArray1::from_vec(py, self.iterations),
        )?;
        d.set_item(
            key(Field::StepTime),
            PyArray1::from_vec(py, self.step_time_us),
        )?;
        d.set_item(
            key(Field::WithinLimits),
            PyArray1::from_vec(py, self.within_limits),
        )?;
        Ok(d)
    }
}

/// The `dof` argument checked: 1 or 2, else `ConfigError` (a `ValueError`).
pub fn dof_arg(dof: i64) -> PyResult<u8> {
    match dof {
        1 => Ok(1),
        2 => Ok(2),
        _ => Err(ConfigError::new_err(format!(
            "dof: {dof} (allowed: 1 or 2)"
        ))),
    }
}

/// The duration key of the `dof` layout.
fn duration_key(dof: u8) -> &'static str {
    if dof == 1 {
        "timing.duration_1dof_s"
    } else {
        "timing.duration_2dof_s"
    }
}

/// Applies the keyword overrides of `simulate` through the CLI's key setter (same checks and
/// messages), naming the argument on error.
pub fn overrides(
    s: &Experiment,
    dof: u8,
    controller: Option<&str>,
    formulation: Option<&str>,
    payload: Option<f64>,
    duration: Option<f64>,
) -> PyResult<Experiment> {
    let mut s = s.clone();
    let mut apply = |arg: &str, key: &str, v: toml::Value| -> PyResult<()> {
        s = set_key(&s, key, v).map_err(|e| ConfigError::new_err(format!("{arg}: {e}")))?;
        Ok(())
    };
    if let Some(c) = controller {
        apply("controller", "controller.kind", parse_value(c))?;
    }
    if let Some(f) = formulation {
        apply("formulation", "multistage.formulation", parse_value(f))?;
    }
    if let Some(p) = payload {
        apply("payload", "uncertainty.payload_kg", toml::Value::Float(p))?;
    }
    if let Some(d) = duration {
        apply("duration", duration_key(dof), toml::Value::Float(d))?;
    }
    Ok(s)
}

/// One closed-loop run (no Python involved: called with the GIL released), stopping between
/// two control steps once `stop()` is true.
fn run(
    s: &Experiment,
    dof: u8,
    cols: Option<&mut Columns>,
    stop: &(dyn Fn() -> bool + Sync),
) -> Result<Summary, String> {
    let mut stop = StopWhen(stop);
    if dof == 1 {
        let mut recs: Vec<&mut dyn Recorder<1>> = vec![&mut stop];
        if let Some(c) = cols {
            recs.push(c);
        }
        run_experiment::<OneDof, 1>(s, &mut recs)
    } else {
        let mut recs: Vec<&mut dyn Recorder<2>> = vec![&mut stop];
        if let Some(c) = cols {
            recs.push(c);
        }
        run_experiment::<TwoDof, 2>(s, &mut recs)
    }
    .map_err(|e| e.to_string())
}

/// `RunError` of a call stopped by its `CancelToken`.
fn cancelled(what: &str) -> PyErr {
    RunError::new_err(format!(
        "{what}: cancelled (CancelToken.cancel() was called)"
    ))
}

fn summary_dict<'py>(py: Python<'py>, s: &Summary) -> PyResult<Bound<'py, PyDict>> {
    let json = serde_json::to_string(s).map_err(|e| RunError::new_err(format!("summary: {e}")))?;
    let obj = py.import("json")?.call_method1("loads", (json,))?;
    Ok(obj.cast_into::<PyDict>()?)
}

/// Runs one closed-loop experiment of `scenario` (default: the default scenario) and returns
/// its summary as a dict (the keys of ``exompc simulate --json``: ``rms_force_n``,
/// ``delta_max_deg``, ``mean_probability``, ``step_time_us``, ...) with, unless
/// ``trace=False``, a ``"trace"`` dict of numpy columns (one row per control step).
///
/// ``controller`` (``"pd"``, ``"nmpc"``, ``"msnmpc"``), ``formulation``, ``payload`` (kg) and
/// ``duration`` (s) override the scenario like the CLI flags. The run goes on a helper thread
/// with the GIL released; Ctrl-C (from the main thread) raises ``KeyboardInterrupt`` within
/// about 50 ms, and ``cancel`` (a ``CancelToken``) stops it from another thread (``RunError``).
/// A run whose trace (or summary) would not fit in 80 % of the available memory raises
/// ``ConfigError`` naming the duration and the limit before anything is allocated.
#[pyfunction]
#[pyo3(signature = (scenario = None, *, controller = None, payload = None, dof = 2, duration = None, formulation = None, trace = true, cancel = None))]
#[allow(clippy::too_many_arguments)]
pub fn simulate<'py>(
    py: Python<'py>,
    scenario: Option<PyRef<'py, PyScenario>>,
    controller: Option<&str>,
    payload: Option<f64>,
    dof: i64,
    duration: Option<f64>,
    formulation: Option<&str>,
    trace: bool,
    cancel: Option<PyRef<'py, CancelToken>>,
) -> PyResult<Bound<'py, PyDict>> {
    catch(|| {
        let dof = dof_arg(dof)?;
        let base = scenario.map_or_else(Experiment::default, |s| s.inner.clone());
        let s = overrides(&base, dof, controller, formulation, payload, duration)?;
        let n = usize::from(dof);
        let scenarios = memory::scenario_count(&s);
        let arg = if duration.is_some() {
            "duration"
        } else {
            duration_key(dof)
        };
        let (per_step, hint) = if trace {
            (
                memory::trace_per_step(n, scenarios) + memory::METRICS_PER_STEP,
                "pass trace=False (the summary alone keeps 16 B per step), a shorter duration \
                 or a longer timing.dt",
            )
        } else {
            (
                memory::METRICS_PER_STEP,
                "use a shorter duration or a longer timing.dt",
            )
        };
        memory::check(arg, &s, dof, per_step, 1, hint)?;
        let mut cols = if trace {
            Some(Columns::with_capacity(s.control_steps(n), n, scenarios)?)
        } else {
            None
        };
        let out = interruptible(py, cancel.as_deref(), |stop| {
            run(&s, dof, cols.as_mut(), stop)
        })?;
        let summary = match out {
            Outcome::Done(r) => r.map_err(RunError::new_err)?,
            Outcome::Cancelled => return Err(cancelled("simulate")),
        };
        let d = summary_dict(py, &summary)?;
        if let Some(c) = cols {
            d.set_item("trace", c.into_dict(py)?)?;
        }
        Ok(d)
    })
}

/// Most threads `run_many` accepts.
const MAX_THREADS: i64 = 1024;

/// Runs every scenario of `scenarios` (in parallel on `threads` threads, default all cores,
/// with the GIL released) and returns their summaries in order. With ``errors="raise"`` the
/// first failed run raises ``RunError``; with ``errors="return"`` a failed run's entry is
/// ``{"error": message}``. Ctrl-C raises ``KeyboardInterrupt`` (the runs stop between two
/// control steps); ``cancel`` stops them from another thread (``RunError``).
#[pyfunction]
#[pyo3(signature = (scenarios, *, dof = 2, threads = None, errors = "raise", cancel = None))]
pub fn run_many<'py>(
    py: Python<'py>,
    scenarios: Vec<PyRef<'py, PyScenario>>,
    dof: i64,
    threads: Option<i64>,
    errors: &str,
    cancel: Option<PyRef<'py, CancelToken>>,
) -> PyResult<Vec<Bound<'py, PyDict>>> {
    catch(|| run_many_impl(py, scenarios, dof, threads, errors, cancel))
}

fn run_many_impl<'py>(
    py: Python<'py>,
    scenarios: Vec<PyRef<'py, PyScenario>>,
    dof: i64,
    threads: Option<i64>,
    errors: &str,
    cancel: Option<PyRef<'py, CancelToken>>,
) -> PyResult<Vec<Bound<'py, PyDict>>> {
    let dof = dof_arg(dof)?;
    let raise = match errors {
        "raise" => true,
        "return" => false,
        other => {
            return Err(ConfigError::new_err(format!(
                "errors: `{other}` (allowed: \"raise\" or \"return\")"
            )))
        }
    };
    let threads = match threads {
        None => None,
        Some(n) if (1..=MAX_THREADS).contains(&n) => Some(n as usize),
        Some(n) => {
            return Err(ConfigError::new_err(format!(
                "threads: {n} (allowed: 1 to {MAX_THREADS}, or None for all cores)"
            )))
        }
    };
    let list: Vec<Experiment> = scenarios.iter().map(|s| s.inner.clone()).collect();
    // The summaries of the runs in flight keep their step times: check the longest run.
    let at_once = threads
        .unwrap_or_else(rayon::current_num_threads)
        .min(list.len());
    if let Some((i, s)) = list
        .iter()
        .enumerate()
        .rev() // the first of the longest
        .max_by_key(|(_, s)| s.control_steps(usize::from(dof)))
    {
        memory::check(
            &format!("scenarios[{i}]: {}", duration_key(dof)),
            s,
            dof,
            memory::METRICS_PER_STEP,
            at_once as u64,
            "use shorter durations, a longer timing.dt or fewer threads",
        )?;
    }
    let out = interruptible(py, cancel.as_deref(), |stop| {
        let go = || {
            list.par_iter()
                .map(|s| {
                    if stop() {
                        Err("not run: stopped".to_string())
                    } else {
                        run(s, dof, None, stop)
                    }
                })
                .collect::<Vec<Result<Summary, String>>>()
        };
        match threads {
            Some(n) => rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map(|p| p.install(go))
                .unwrap_or_else(|_| go()),
            None => go(),
        }
    })?;
    let results = match out {
        Outcome::Done(r) => r,
        Outcome::Cancelled => return Err(cancelled("run_many")),
    };
    results
        .into_iter()
        .enumerate()
        .map(|(i, r)| match r {
            Ok(s) => summary_dict(py, &s),
            Err(e) if raise => Err(RunError::new_err(format!("run {i}: {e}"))),
            Err(e) => {
                let d = PyDict::new(py);
                d.set_item("error", e)?;
                Ok(d)
            }
        })
        .collect()
}

/// The plant and sensors of one layout (one lives per `Simulator`; the size gap is harmless).
#[allow(clippy::large_enum_variant)]
enum Loop {
    One(Plant<1, <OneDof as Dof<1>>::Traj>, Sensors<1>),
    Two(Plant<2, <TwoDof as Dof<2>>::Traj>, Sensors<2>),
}

/// `(t, q, qd, force)` as returned by `Simulator.measure`.
type Sample<'py> = (
    f64,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
);

fn parts<D: Dof<N>, const N: usize>(s: &Experiment) -> (Plant<N, D::Traj>, Sensors<N>) {
    (
        Plant::new(plant_params::<D, N>(s), D::trajectory(s)),
        Sensors::new(uncertainty(s), s.uncertainty.filter_window).with_faults(&s.faults),
    )
}

/// The simulated human-exoskeleton plant with its sensor chain, to close the loop from Python
/// with any controller: each period call ``measure()`` once (sensors sampled at the current
/// time, returns the filtered ``(t, q, qd, force)`` a controller reads), then
/// ``advance(torque)`` (the torque held over one control period).
///
/// ``Simulator(s)`` driven by ``Controller(s)`` reproduces ``simulate(s)`` step for step.
///
/// Thread-safe: it may be passed to and used from any thread (its calls hold the GIL).
#[pyclass(module = "exompc", name = "Simulator")]
pub struct PySimulator {
    inner: Loop,
    steps: usize,
    dt: f64,
}

macro_rules! with_loop {
    ($self:expr, $p:ident, $s:ident, $body:expr) => {
        match &mut $self.inner {
            Loop::One($p, $s) => $body,
            Loop::Two($p, $s) => $body,
        }
    };
}

#[pymethods]
impl PySimulator {
    /// The plant of `scenario` (default: the default scenario) in the `dof` layout.
    #[new]
    #[pyo3(signature = (scenario = None, *, dof = 2))]
    fn new(scenario: Option<PyRef<'_, PyScenario>>, dof: i64) -> PyResult<Self> {
        catch(|| {
            let dof = dof_arg(dof)?;
            let s = scenario.map_or_else(Experiment::default, |s| s.inner.clone());
            s.validate()
                .map_err(|e| ConfigError::new_err(e.to_string()))?;
            s.check_trajectory(usize::from(dof))
                .map_err(|e| ConfigError::new_err(e.to_string()))?;
            let inner = if dof == 1 {
                let (p, se) = parts::<OneDof, 1>(&s);
                Loop::One(p, se)
            } else {
                let (p, se) = parts::<TwoDof, 2>(&s);
                Loop::Two(p, se)
            };
            Ok(PySimulator {
                inner,
                steps: s.control_steps(usize::from(dof)),
                dt: s.timing.dt,
            })
        })
    }

    /// Number of control steps of the scenario's run (duration / dt).
    #[getter]
    fn steps(&self) -> usize {
        self.steps
    }

    /// Control period (s).
    #[getter]
    fn dt(&self) -> f64 {
        self.dt
    }

    /// Current time (s).
    #[getter]
    fn t(&mut self) -> PyResult<f64> {
        catch(|| Ok(with_loop!(self, p, _s, p.time())))
    }

    /// Samples the sensors at the current time; returns the filtered ``(t, q, qd, force)``
    /// (numpy float64 arrays). Call once per period: the filters advance on every call.
    fn measure<'py>(&mut self, py: Python<'py>) -> PyResult<Sample<'py>> {
        catch(|| {
            Ok(with_loop!(self, p, s, {
                let st = *p.state();
                let (_raw, m) = s.read(p.time(), &st.robot.q, &st.robot.qd, &p.strap_force());
                (m.t, array(py, &m.q), array(py, &m.qd), array(py, &m.force))
            }))
        })
    }

    /// Advances the plant by one control period with robot torque `torque` (N·m) held.
    fn advance(&mut self, torque: &Bound<'_, PyAny>) -> PyResult<()> {
        catch(|| {
            match &mut self.inner {
                Loop::One(p, _) => p.step(&vector::<1>("torque", torque)?),
                Loop::Two(p, _) => p.step(&vector::<2>("torque", torque)?),
            }
            Ok(())
        })
    }

    /// The true state: dict of robot and human angles/velocities, desired angles, true strap
    /// forces and human torque (numpy arrays).
    fn state<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        catch(|| {
            let d = PyDict::new(py);
            with_loop!(self, p, _s, {
                let st = *p.state();
                d.set_item("t", p.time())?;
                d.set_item("q_robot", array(py, &st.robot.q))?;
                d.set_item("qd_robot", array(py, &st.robot.qd))?;
                d.set_item("q_human", array(py, &st.human.q))?;
                d.set_item("qd_human", array(py, &st.human.qd))?;
                d.set_item("q_desired", array(py, &p.trajectory().eval(p.time()).0))?;
                d.set_item("force_true", array(py, &p.strap_force()))?;
                d.set_item("torque_human", array(py, &p.human_torque()))?;
            });
            Ok(d)
        })
    }
}

/// The operating-envelope scan of `exompc envelope` (classification of every run and the
/// per-cell verdict of MS-NMPC against NMPC), as its JSON text (`envelope.json`). `sets` are
/// `key=v1,v2` grids (their Cartesian product); without them the standard envelope runs.
/// The scan runs with the GIL released; Ctrl-C raises ``KeyboardInterrupt`` and ``cancel``
/// stops it from another thread (``RunError``).
#[pyfunction]
#[pyo3(signature = (scenario = None, *, sets = Vec::new(), payloads = None, controllers = None, dof = 2, monitors = true, cancel = None))]
#[allow(clippy::too_many_arguments)]
pub fn envelope_json<'py>(
    py: Python<'py>,
    scenario: Option<PyRef<'py, PyScenario>>,
    sets: Vec<String>,
    payloads: Option<Vec<f64>>,
    controllers: Option<Vec<String>>,
    dof: i64,
    monitors: bool,
    cancel: Option<PyRef<'py, CancelToken>>,
) -> PyResult<String> {
    use exompc_study::envelope::{scan_until, without_monitors, Grid};
    catch(|| {
        let dof = dof_arg(dof)?;
        let mut base = scenario.map_or_else(Experiment::default, |s| s.inner.clone());
        if !monitors {
            base = without_monitors(&base);
        }
        let mut grid = if sets.is_empty() {
            Grid::standard()
        } else {
            Grid::product(&sets, dof, vec![0.0, 1.0, 2.0, 3.0], vec![])
                .map_err(|e| ConfigError::new_err(e.to_string()))?
        };
        if let Some(p) = payloads {
            grid.payloads_kg = p;
        }
        match controllers {
            Some(c) => grid.controllers = c,
            None if grid.controllers.is_empty() => {
                grid.controllers = vec!["nmpc".into(), "msnmpc".into()]
            }
            None => {}
        }
        // Every run in flight keeps its whole trace (for the stability classification; the
        // multi-stage runs' probabilities on the heap).
        let mut longest: Option<(u64, String, Experiment, u8)> = None;
        for cell in &grid.cells {
            let s = Grid::scenario(&base, cell).map_err(|e| ConfigError::new_err(e.to_string()))?;
            let steps = s.control_steps(usize::from(cell.dof.clamp(1, 2))) as u64;
            if longest.as_ref().is_none_or(|l| steps > l.0) {
                longest = Some((steps, cell.name.clone(), s, cell.dof.clamp(1, 2)));
            }
        }
        let jobs = grid.cells.len() * grid.payloads_kg.len() * grid.controllers.len();
        if let Some((_, name, s, d)) = longest {
            let row = if d == 1 {
                std::mem::size_of::<exompc::sim::TraceRow<1>>()
            } else {
                std::mem::size_of::<exompc::sim::TraceRow<2>>()
            };
            let per_step = (row + 8 * exompc::config::scenarios::count(&s) + 32) as u64
                + memory::METRICS_PER_STEP;
            memory::check(
                &format!("cell `{name}`: {}", duration_key(d)),
                &s,
                d,
                per_step,
                rayon::current_num_threads().min(jobs) as u64,
                "use a shorter duration or a longer timing.dt",
            )?;
        }
        let criteria = exompc::sim::StabilityCriteria::default();
        let out = interruptible(py, cancel.as_deref(), |stop| {
            scan_until(&base, &grid, &criteria, &|| {}, stop)
        })?;
        let env = match out {
            Outcome::Done(r) => r.map_err(|e| ConfigError::new_err(e.to_string()))?,
            Outcome::Cancelled => return Err(cancelled("envelope")),
        };
        serde_json::to_string(&env).map_err(|e| RunError::new_err(e.to_string()))
    })
}
