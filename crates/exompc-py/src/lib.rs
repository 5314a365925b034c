//! Python bindings of exompc (module `exompc._core`; the public package is `exompc`, see
//! `python/exompc/__init__.py`): scenarios with the CLI's key checks, the closed-loop
//! simulator, the controllers with one `step` call, and parallel batches of runs.
//!
//! Long runs release the GIL (`Python::detach`) and poll Ctrl-C (`guard::interruptible`); the
//! control step itself allocates nothing in Rust (its fixed-size buffers live in the
//! controller). Every entry point runs under `guard::catch`: a Rust panic reaches Python as a
//! `RuntimeError`, never as a `PanicException`.

use pyo3::prelude::*;

mod controller;
mod convert;
mod guard;
mod memory;
mod scenario;
mod simulate;

pyo3::create_exception!(
    exompc,
    ConfigError,
    pyo3::exceptions::PyValueError,
    "A scenario value, key or argument is invalid; the message names the field and its allowed range."
);

pyo3::create_exception!(
    exompc,
    RunError,
    pyo3::exceptions::PyRuntimeError,
    "A run could not complete (e.g. the simulated plant diverged)."
);

/// The native core of the `exompc` package.
#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("ConfigError", py.get_type::<ConfigError>())?;
    m.add("RunError", py.get_type::<RunError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("STATUS_NAMES", convert::STATUS_NAMES.to_vec())?;
    m.add("TRACE_COLUMNS", convert::trace_columns(py)?)?;
    m.add_class::<scenario::PyScenario>()?;
    m.add_class::<controller::PyController>()?;
    m.add_class::<simulate::PySimulator>()?;
    m.add_class::<guard::CancelToken>()?;
    m.add_function(wrap_pyfunction!(guard::_raise_panic, m)?)?;
    m.add_function(wrap_pyfunction!(simulate::simulate, m)?)?;
    m.add_function(wrap_pyfunction!(simulate::run_many, m)?)?;
    m.add_function(wrap_pyfunction!(simulate::envelope_json, m)?)?;
    m.add_function(wrap_pyfunction!(scenario::default_config_toml, m)?)?;
    Ok(())
}
