//! `exompc.Controller`: one of the scenario's controllers with a `step` call per period.
//!
//! A controller is bound to the thread that created it: the Rust controller lives in that
//! thread's slot table (`SLOTS`), and the Python object holds only its index and the owner
//! thread. A call from another thread raises `RuntimeError` naming the rule (the Rust
//! controllers are not `Send`: the registry may hold any controller).

use crate::convert::{array, vector, write_into, STATUS_NAMES};
use crate::guard::catch;
use crate::scenario::PyScenario;
use crate::simulate::{dof_arg, overrides};
use crate::ConfigError;
use exompc::config::Experiment;
use exompc::control::{ControlOutput, Controller, Measurement};
use exompc::scenario::{build_controller, build_supervised, OneDof, TwoDof};
use numpy::PyArray1;
use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::PyString;
use std::cell::RefCell;
use std::thread::ThreadId;

enum Ctl {
    One(Box<dyn Controller<1>>),
    Two(Box<dyn Controller<2>>),
}

fn build(s: &Experiment, dof: u8, supervised: bool) -> PyResult<Ctl> {
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

/// The controllers created on this thread, by slot index (`None`: freed).
#[derive(Default)]
struct Slots {
    items: Vec<Option<Ctl>>,
    free: Vec<usize>,
}

thread_local! {
    static SLOTS: RefCell<Slots> = RefCell::new(Slots::default());
}

/// Stores `c` in this thread's table; returns its slot.
fn insert(c: Ctl) -> PyResult<usize> {
    SLOTS
        .try_with(|t| {
            let mut t = t.borrow_mut();
            match t.free.pop() {
                Some(i) => {
                    t.items[i] = Some(c);
                    i
                }
                None => {
                    t.items.push(Some(c));
                    t.items.len() - 1
                }
            }
        })
        .map_err(|_| PyRuntimeError::new_err("Controller: this thread is shutting down"))
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
///
/// Thread rule: a controller belongs to the thread that created it; calling it from another
/// thread raises ``RuntimeError`` (create one controller per thread instead).
#[pyclass(module = "exompc", name = "Controller", subclass, frozen)]
pub struct PyController {
    owner: ThreadId,
    owner_name: String,
    slot: usize,
    scenario: Experiment,
    dof: u8,
    supervised: bool,
    status_names: Vec<Py<PyString>>,
}

macro_rules! with_ctl {
    ($self:expr, $c:ident, $body:expr) => {
        $self.with(|ctl| match ctl {
            Ctl::One($c) => $body,
            Ctl::Two($c) => $body,
        })
    };
}

impl PyController {
    /// Runs `f` on the Rust controller; `RuntimeError` on a thread other than the owner's.
    /// `f` must not call into Python (no Python object is created while the table is held).
    fn with<R>(&self, f: impl FnOnce(&mut Ctl) -> R) -> PyResult<R> {
        let here = std::thread::current();
        if here.id() != self.owner {
            return Err(PyRuntimeError::new_err(format!(
                "this Controller belongs to the thread that created it ({}) and cannot be \
                 used from another thread; create one Controller per thread (Scenario, \
                 Simulator and CancelToken objects may be shared)",
                self.owner_name
            )));
        }
        let gone = || PyRuntimeError::new_err("Controller: its thread's table is gone");
        SLOTS
            .try_with(|t| {
                let mut t = t.try_borrow_mut().map_err(|_| gone())?;
                let c = t.items.get_mut(self.slot).and_then(Option::as_mut);
                c.map(f).ok_or_else(gone)
            })
            .map_err(|_| gone())?
    }

    fn finish<'py, const N: usize>(
        &self,
        py: Python<'py>,
        o: ControlOutput<N>,
        out: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyString>)> {
        let status = self.status_names[usize::from(o.status.code())]
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

impl Drop for PyController {
    fn drop(&mut self) {
        // On the owner thread the slot is freed; elsewhere (or if the table is busy) the
        // controller stays until the owner thread ends and its table is dropped.
        if std::thread::current().id() == self.owner {
            let _ = SLOTS.try_with(|t| {
                if let Ok(mut t) = t.try_borrow_mut() {
                    if let Some(c) = t.items.get_mut(self.slot) {
                        *c = None;
                        t.free.push(self.slot);
                    }
                }
            });
        }
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
        dof: i64,
        supervised: bool,
    ) -> PyResult<Self> {
        catch(|| {
            let dof = dof_arg(dof)?;
            let base = scenario.map_or_else(Experiment::default, |s| s.inner.clone());
            let s = overrides(&base, dof, kind, None, None, None)?;
            let slot = insert(build(&s, dof, supervised)?)?;
            let owner_name = py
                .import("threading")?
                .call_method0("current_thread")?
                .getattr("name")?
                .extract::<String>()
                .unwrap_or_else(|_| "another thread".to_string());
            Ok(PyController {
                owner: std::thread::current().id(),
                owner_name: format!("thread {owner_name:?}"),
                slot,
                scenario: s,
                dof,
                supervised,
                status_names: STATUS_NAMES
                    .iter()
                    .map(|n| PyString::intern(py, n).unbind())
                    .collect(),
            })
        })
    }

    /// One control period: filtered measurement in, ``(torque, status)`` out.
    #[pyo3(signature = (t, q, qd, force, out = None))]
    fn step<'py>(
        &self,
        py: Python<'py>,
        t: f64,
        q: &Bound<'py, PyAny>,
        qd: &Bound<'py, PyAny>,
        force: &Bound<'py, PyAny>,
        out: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyString>)> {
        catch(|| {
            if self.dof == 1 {
                let m = Measurement {
                    t,
                    q: vector::<1>("q", q)?,
                    qd: vector::<1>("qd", qd)?,
                    force: vector::<1>("force", force)?,
                };
                let o = self.with(|c| match c {
                    Ctl::One(c) => Some(c.step(&m)),
                    Ctl::Two(_) => None,
                })?;
                self.finish(py, o.ok_or_else(mismatch)?, out)
            } else {
                let m = Measurement {
                    t,
                    q: vector::<2>("q", q)?,
                    qd: vector::<2>("qd", qd)?,
                    force: vector::<2>("force", force)?,
                };
                let o = self.with(|c| match c {
                    Ctl::Two(c) => Some(c.step(&m)),
                    Ctl::One(_) => None,
                })?;
                self.finish(py, o.ok_or_else(mismatch)?, out)
            }
        })
    }

    /// Back to the state right after construction (initial torque, estimator, probabilities).
    fn reset(&self) -> PyResult<()> {
        catch(|| {
            let fresh = build(&self.scenario, self.dof, self.supervised)?;
            self.with(|c| *c = fresh)
        })
    }

    /// Controller name (``"pd"``, ``"nmpc"``, ``"msnmpc"``).
    #[getter]
    fn name(&self) -> PyResult<&'static str> {
        catch(|| with_ctl!(self, c, c.name()))
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
    fn probabilities<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArray1<f64>>>> {
        catch(|| {
            let p = with_ctl!(self, c, c.probabilities().map(<[f64]>::to_vec))?;
            Ok(p.map(|p| PyArray1::from_vec(py, p)))
        })
    }

    /// Per-scenario disturbance estimates (N·m) as an array of shape ``(S, dof)``; ``None``
    /// for controllers without scenarios.
    #[getter]
    fn disturbances<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        use numpy::PyArrayMethods;
        catch(|| {
            let v = with_ctl!(self, c, {
                c.probabilities().map(<[f64]>::len).map(|n| {
                    let mut v = Vec::with_capacity(n * usize::from(self.dof));
                    for i in 0..n {
                        if let Some(d) = c.disturbance(i) {
                            v.extend_from_slice(d.as_slice());
                        }
                    }
                    (n, v)
                })
            })?;
            let Some((n, v)) = v else {
                return Ok(None);
            };
            let a = PyArray1::from_vec(py, v).reshape([n, usize::from(self.dof)])?;
            Ok(Some(a.into_any()))
        })
    }

    /// The torque applied in the previous period, ``T_R(k-1)`` (N·m).
    #[getter]
    fn previous_torque<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        catch(|| {
            let v = with_ctl!(self, c, c.previous_torque().as_slice().to_vec())?;
            Ok(PyArray1::from_vec(py, v))
        })
    }

    fn __repr__(&self) -> PyResult<String> {
        Ok(format!(
            "Controller(kind={:?}, dof={}, supervised={})",
            self.name()?,
            self.dof,
            if self.supervised { "True" } else { "False" }
        ))
    }
}

/// The layout of a controller differs from its `dof` (cannot happen: built together).
fn mismatch() -> PyErr {
    PyRuntimeError::new_err("Controller: internal layout mismatch")
}
