//! `exompc.Scenario`: a validated scenario, loaded and saved as TOML, read and written key by
//! key with the CLI's checks and messages (`exompc_study::io`).

use crate::convert::{py_to_toml, toml_to_py};
use crate::guard::{catch, os_error};
use crate::ConfigError;
use exompc::config::Experiment;
use exompc_study::io;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};
use std::io::Write;
use std::path::{Path, PathBuf};

/// A complete, validated scenario (plant, human, controller, estimator, faults, monitors).
///
/// ``Scenario()`` and ``Scenario.default()`` give the embedded default scenario (the output of
/// ``exompc config``); ``Scenario.load(path)`` reads a TOML file that overrides some keys.
/// Keys are dotted paths such as ``"uncertainty.payload_kg"``: ``s["controller.np"] = 30`` or
/// ``s.set(...)`` checks the key and validates the whole scenario exactly as the CLI does,
/// raising ``exompc.ConfigError`` (a ``ValueError``) that names the field and its range.
#[pyclass(module = "exompc", name = "Scenario", eq)]
#[derive(Clone, PartialEq)]
pub struct PyScenario {
    pub inner: Experiment,
}

fn config_err(msg: impl Into<String>) -> PyErr {
    ConfigError::new_err(msg.into())
}

#[pymethods]
impl PyScenario {
    /// The default scenario, or the scenario of TOML text `toml` (partial override of the
    /// default, validated).
    #[new]
    #[pyo3(signature = (toml = None))]
    fn new(toml: Option<&str>) -> PyResult<Self> {
        catch(|| match toml {
            None => Ok(Self::default()),
            Some(t) => Self::from_toml(t),
        })
    }

    /// The embedded default scenario (2-DOF swing, MS-NMPC, 20 s).
    #[staticmethod]
    #[allow(clippy::should_implement_trait)]
    pub fn default() -> Self {
        PyScenario {
            inner: Experiment::default(),
        }
    }

    /// Loads a TOML scenario file (keys it names override the default); validated. A file
    /// that cannot be read raises ``OSError`` (``FileNotFoundError``, ``PermissionError``,
    /// ...); bad content raises ``ConfigError`` naming the file and the key.
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        catch(|| {
            let text = read_capped(&path)?;
            let text = String::from_utf8(text).map_err(|_| {
                config_err(format!(
                    "config file {}: not UTF-8 text (a TOML file is expected)",
                    path.display()
                ))
            })?;
            let base = path.parent().unwrap_or(Path::new(""));
            io::parse_scenario_with_origins_in(&text, base)
                .map(|(inner, _)| PyScenario { inner })
                .map_err(|m| config_err(format!("config file {}: {m}", path.display())))
        })
    }

    /// Parses TOML text (keys it names override the default); validated.
    #[staticmethod]
    fn from_toml(text: &str) -> PyResult<Self> {
        catch(|| {
            io::parse_scenario(text)
                .map(|inner| PyScenario { inner })
                .map_err(config_err)
        })
    }

    /// The scenario as TOML text (every key), loadable by ``Scenario.from_toml`` and the CLI.
    fn to_toml(&self) -> PyResult<String> {
        catch(|| {
            toml::to_string_pretty(&self.inner)
                .map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(e.to_string()))
        })
    }

    /// Writes the scenario as TOML to `path` atomically (a temporary file next to it, synced
    /// and renamed; removed on failure). A folder that is missing or read-only raises
    /// ``OSError`` (``FileNotFoundError``, ``PermissionError``, ...) naming the path.
    fn save(&self, path: PathBuf) -> PyResult<()> {
        catch(|| {
            let text = self.to_toml()?;
            write_atomic(&path, text.as_bytes())
        })
    }

    /// The value of a key by dotted path (a dict for a table, ``None`` for an unset optional
    /// key). Unknown keys raise ``ConfigError`` with the closest valid name.
    fn get<'py>(&self, py: Python<'py>, key: &str) -> PyResult<Bound<'py, PyAny>> {
        catch(
            || match io::get_key(&self.inner, key).map_err(config_err)? {
                Some(v) => toml_to_py(py, &v),
                None => Ok(py.None().into_bound(py)),
            },
        )
    }

    /// Sets a key by dotted path to `value` (number, bool, string, list or dict; a string is
    /// read like a command-line value, e.g. ``"coupled"`` or ``"0.5"``), then validates the
    /// whole scenario. On error the scenario is unchanged and ``ConfigError`` names the field.
    fn set(&mut self, key: &str, value: &Bound<'_, PyAny>) -> PyResult<()> {
        catch(|| {
            let v = py_to_toml(key, value)?;
            self.inner = io::set_key(&self.inner, key, v).map_err(config_err)?;
            Ok(())
        })
    }

    /// A copy with the given keys set: ``s.replace({"uncertainty.payload_kg": 1.0})`` or
    /// ``s.replace(**{"controller.np": 30})``. The keys are validated together, so keys that
    /// depend on each other change in one call: ``s.replace({"trajectory.kind": "recorded",
    /// "trajectory.file": "walk.csv"})`` (a gait file is read relative to the working folder).
    #[pyo3(signature = (updates = None, **kwargs))]
    fn replace(
        &self,
        updates: Option<&Bound<'_, PyDict>>,
        kwargs: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        catch(|| {
            let mut changes = Vec::new();
            for d in [updates, kwargs].into_iter().flatten() {
                for (k, v) in d.iter() {
                    let key = k.extract::<String>()?;
                    let value = py_to_toml(&key, &v)?;
                    changes.push((key, value));
                }
            }
            let inner = io::set_keys(&self.inner, &changes, std::path::Path::new(""))
                .map_err(config_err)?;
            Ok(Self { inner })
        })
    }

    /// Every settable leaf key as a dotted path, in file order.
    fn keys(&self) -> PyResult<Vec<String>> {
        catch(|| self.keys_impl())
    }

    /// The whole scenario as nested dicts.
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        catch(|| {
            let tree = toml::Value::try_from(&self.inner)
                .map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(e.to_string()))?;
            toml_to_py(py, &tree)
        })
    }

    /// Checks every field again (always true for a Scenario built through this API).
    fn validate(&self) -> PyResult<()> {
        catch(|| exompc::scenario::validate(&self.inner).map_err(|e| config_err(e.to_string())))
    }

    /// An independent copy.
    fn copy(&self) -> Self {
        self.clone()
    }

    fn __copy__(&self) -> Self {
        self.clone()
    }

    fn __deepcopy__(&self, _memo: &Bound<'_, PyAny>) -> Self {
        self.clone()
    }

    fn __getitem__<'py>(&self, py: Python<'py>, key: &str) -> PyResult<Bound<'py, PyAny>> {
        self.get(py, key)
    }

    fn __setitem__(&mut self, key: &str, value: &Bound<'_, PyAny>) -> PyResult<()> {
        self.set(key, value)
    }

    /// Pickles as TOML text (so scenarios travel to Ray workers and processes).
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<Bound<'py, PyTuple>> {
        catch(|| {
            let py = slf.py();
            let text = slf.borrow().to_toml()?;
            let ctor = py.get_type::<PyScenario>().getattr("from_toml")?;
            PyTuple::new(py, [ctor, PyTuple::new(py, [text])?.into_any()])
        })
    }

    fn __repr__(&self) -> String {
        let s = &self.inner;
        format!(
            "Scenario(controller={}, payload_kg={}, dt={}, duration_2dof_s={}, duration_1dof_s={})",
            s.controller.kind,
            s.uncertainty.payload_kg,
            s.timing.dt,
            s.timing.duration_2dof_s,
            s.timing.duration_1dof_s
        )
    }
}

impl PyScenario {
    fn keys_impl(&self) -> PyResult<Vec<String>> {
        let tree = toml::Value::try_from(&self.inner)
            .map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(e.to_string()))?;
        let mut out = Vec::new();
        fn walk(v: &toml::Value, prefix: &str, out: &mut Vec<String>) {
            match v {
                toml::Value::Table(t) => {
                    for (k, x) in t {
                        let p = if prefix.is_empty() {
                            k.clone()
                        } else {
                            format!("{prefix}.{k}")
                        };
                        walk(x, &p, out);
                    }
                }
                _ => out.push(prefix.to_string()),
            }
        }
        walk(&tree, "", &mut out);
        Ok(out)
    }
}

/// Largest scenario file `Scenario.load` reads (a scenario is a few kB; recorded gaits are
/// separate files).
const MAX_SCENARIO_BYTES: u64 = 16 << 20;

/// The bytes of the file at `path`, refusing one larger than [`MAX_SCENARIO_BYTES`] (e.g.
/// `/dev/zero`) instead of reading until memory runs out.
fn read_capped(path: &Path) -> PyResult<Vec<u8>> {
    use std::io::Read;
    let err = |e: std::io::Error| os_error("cannot read scenario file", path, &e);
    let f = std::fs::File::open(path).map_err(err)?;
    let mut bytes = Vec::new();
    f.take(MAX_SCENARIO_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(err)?;
    if bytes.len() as u64 > MAX_SCENARIO_BYTES {
        return Err(config_err(format!(
            "config file {}: larger than {} MiB (a scenario file is a few kB)",
            path.display(),
            MAX_SCENARIO_BYTES >> 20
        )));
    }
    Ok(bytes)
}

/// Writes `bytes` to `path` through a temporary file in the same folder (synced, renamed over
/// `path`; removed on failure), with `OSError`s naming the path.
fn write_atomic(path: &Path, bytes: &[u8]) -> PyResult<()> {
    let name = path
        .file_name()
        .ok_or_else(|| config_err(format!("save: {} names no file", path.display())))?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(format!(".tmp.{}", std::process::id()));
    let tmp = path.with_file_name(tmp_name);
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        drop(f);
        std::fs::rename(&tmp, path)
    })();
    result.map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        os_error("cannot save scenario to", path, &e)
    })
}

/// The default scenario as commented TOML (the output of ``exompc config``).
#[pyfunction]
pub fn default_config_toml() -> PyResult<String> {
    catch(|| {
        io::default_config_toml()
            .map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(e.to_string()))
    })
}
