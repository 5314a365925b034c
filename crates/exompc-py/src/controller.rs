//! `exompc.Controller`: one of the scenario's controllers with a `step` call per period.

use crate::convert::{array, status_code, vector, write_into, STATUS_NAMES};
use crate::scenario::PyScenario;
use crate::simulate::overrides;
use crate::ConfigError;
use exompc::config::Scenario;
use exompc::control::{ControlOutput, Controller, Measurement};
use exompc::scenario::{build_controller, build_supervised, OneDof, TwoDof};
use numpy::PyArray1;
use pyo3::prelude::*;
use pyo3::types::PyString;

enum Ctl {
    One(Box<dyn Controller<1>>),
    Two(Box<dyn Controller<2>>),
}

fn build(s: &Scenario, dof: u8, supervised: bool) -> PyResult<Ctl> {
    let err = |e: exompc::scenario::RunError| ConfigError::new_err(e.to_string());
    let kind = s.controller.kind;
    Ok(if dof == 1 {
        Ctl::One(if supervised {
            Box::new(build_supervised::<OneDof, 1>(s, kind).map_err(err)?)
        } else {
            build_controller::<OneDof, 1>(s, kind).map_err(err)?
        })
    } else {
        Ctl::Two(if supervised {
            Box::new(build_supervised::<TwoDof, 2>(s, kind).map_err(err)?)
        } else {
            build_controller::<TwoDof, 2>(s, kind).map_err(err)?
        })
    })
}

/// A feedback controller of the scenario (``kind``: ``"pd"``, ``"nmpc"`` or ``"msnmpc"``;
/// default the scenario's ``controller.kind``), for the 1- or 2-DOF layout.
///
/// Call ``step(t, q, qd, force)`` once per control period (``scenario.timing.dt``) with the
/// robot joint angles (rad), filtered velocities (rad/s) and filtered strap forces (N, thigh
/// then shank; 1-DOF: shank only) as float64 arrays of shape ``(dof,)`` (or lists); it returns
/// ``(torque, status)``: the robot joint torque (N·m), always within the torque and
/// torque-rate limits, and the outcome name (``"ok"``, ``"max_iterations"``, ``"max_time"``,
/// ``"solver_failed"``, ``"bad_measurement"``, ``"monitor_tripped"``). With ``out=`` the
/// torque is written into that array instead of a new one. The Rust step allocates nothing.
///
/// ``supervised=True`` (default) wraps the controller in the safety supervisor of the
/// scenario's ``[monitors]``, exactly as ``simulate`` runs it.
#[pyclass(module = "exompc", name = "Controller", subclass, unsendable)]
pub struct PyController {
    ctl: Ctl,
    scenario: Scenario,
    dof: u8,
    supervised: bool,
    status_names: Vec<Py<PyString>>,
}

macro_rules! with_ctl {
    ($self:expr, $c:ident, $body:expr) => {
        match &$self.ctl {
            Ctl::One($c) => $body,
            Ctl::Two($c) => $body,
        }
    };
}

impl PyController {
    fn finish<'py, const N: usize>(
        &self,
        py: Python<'py>,
        o: ControlOutput<N>,
        out: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyString>)> {
        let status = self.status_names[usize::from(status_code(o.status))]
            .bind(py)
            .clone();
        let torque = match out {
            Some(a) => {
                write_into(a, &o.torque)?;
                a.clone()
            }
            None => array(py, &o.torque).into_any(),
        };
        Ok((torque, status))
    }
}

#[pymethods]
impl PyController {
    #[new]
    #[pyo3(signature = (scenario = None, kind = None, *, dof = 2, supervised = true))]
    fn new(
        py: Python<'_>,
        scenario: Option<PyRef<'_, PyScenario>>,
        kind: Option<&str>,
        dof: u8,
        supervised: bool,
    ) -> PyResult<Self> {
        let base = scenario.map_or_else(Scenario::default, |s| s.inner.clone());
        let s = overrides(&base, dof, kind, None, None, None)?;
        Ok(PyController {
            ctl: build(&s, dof, supervised)?,
            scenario: s,
            dof,
            supervised,
            status_names: STATUS_NAMES
                .iter()
                .map(|n| PyString::intern(py, n).unbind())
                .collect(),
        })
    }

    /// One control period: filtered measurement in, ``(torque, status)`` out.
    #[pyo3(signature = (t, q, qd, force, out = None))]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        t: f64,
        q: &Bound<'py, PyAny>,
        qd: &Bound<'py, PyAny>,
        force: &Bound<'py, PyAny>,
        out: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyString>)> {
        match &mut self.ctl {
            Ctl::One(c) => {
                let m = Measurement {
                    t,
                    q: vector::<1>("q", q)?,
                    qd: vector::<1>("qd", qd)?,
                    force: vector::<1>("force", force)?,
                };
                let o = c.step(&m);
                self.finish(py, o, out)
            }
            Ctl::Two(c) => {
                let m = Measurement {
                    t,
                    q: vector::<2>("q", q)?,
                    qd: vector::<2>("qd", qd)?,
                    force: vector::<2>("force", force)?,
                };
                let o = c.step(&m);
                self.finish(py, o, out)
            }
        }
    }

    /// Back to the state right after construction (initial torque, estimator, probabilities).
    fn reset(&mut self) -> PyResult<()> {
        self.ctl = build(&self.scenario, self.dof, self.supervised)?;
        Ok(())
    }

    /// Controller name (``"pd"``, ``"nmpc"``, ``"msnmpc"``).
    #[getter]
    fn name(&self) -> &'static str {
        with_ctl!(self, c, c.name())
    }

    /// Number of joints (1 or 2).
    #[getter]
    fn dof(&self) -> u8 {
        self.dof
    }

    /// The scenario the controller was built from (a copy).
    #[getter]
    fn scenario(&self) -> PyScenario {
        PyScenario {
            inner: self.scenario.clone(),
        }
    }

    /// Scenario probabilities ``μ_i(k)`` (paper eqs. 10-11) as an array of shape ``(S,)``;
    /// ``None`` for controllers without scenarios.
    #[getter]
    fn probabilities<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        with_ctl!(
            self,
            c,
            c.probabilities().map(|p| PyArray1::from_slice(py, p))
        )
    }

    /// Per-scenario disturbance estimates (N·m) as an array of shape ``(S, dof)``; ``None``
    /// for controllers without scenarios.
    #[getter]
    fn disturbances<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        use numpy::PyArrayMethods;
        with_ctl!(self, c, {
            let Some(n) = c.probabilities().map(<[f64]>::len) else {
                return Ok(None);
            };
            let mut v = Vec::with_capacity(n * usize::from(self.dof));
            for i in 0..n {
                if let Some(d) = c.disturbance(i) {
                    v.extend_from_slice(d.as_slice());
                }
            }
            let a = PyArray1::from_vec(py, v).reshape([n, usize::from(self.dof)])?;
            Ok(Some(a.into_any()))
        })
    }

    /// The torque applied in the previous period, ``T_R(k-1)`` (N·m).
    #[getter]
    fn previous_torque<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        with_ctl!(
            self,
            c,
            PyArray1::from_slice(py, c.previous_torque().as_slice())
        )
    }

    fn __repr__(&self) -> String {
        format!(
            "Controller(kind={:?}, dof={}, supervised={})",
            self.name(),
            self.dof,
            if self.supervised { "True" } else { "False" }
        )
    }
}
