//! Conversions between Python objects, TOML values, numpy arrays and nalgebra vectors.

use exompc::control::StepStatus;
use exompc::sim::trace::{Field, Per, TraceColumn, TRACE_COLUMNS};
use nalgebra::SVector;
use numpy::{PyArray1, PyArrayDescrMethods, PyArrayMethods, PyUntypedArray, PyUntypedArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};

/// Names of the step outcomes, indexed by their code ([`StepStatus::code`]).
pub const STATUS_NAMES: [&str; StepStatus::ALL.len()] = {
    let mut names = [""; StepStatus::ALL.len()];
    let mut i = 0;
    while i < names.len() {
        names[i] = StepStatus::ALL[i].name();
        i += 1;
    }
    names
};

/// The trace's per-joint and per-strap columns that Python returns (those of the library's
/// column table with a Python key), in table order.
pub fn trace_vector_columns() -> impl Iterator<Item = &'static TraceColumn> {
    TRACE_COLUMNS
        .iter()
        .filter(|c| c.python.is_some() && matches!(c.per, Per::Joint | Per::Strap))
}

/// The Python trace key of `field` (the column table's).
pub fn trace_key(field: Field) -> &'static str {
    TRACE_COLUMNS
        .iter()
        .find(|c| c.field == field)
        .and_then(|c| c.python)
        .unwrap_or("?")
}

/// The column table for Python (`exompc.TRACE_COLUMNS`): one dict per entry with `python`
/// (the trace key), `csv` (the CSV column or its prefix), `per` (`step`, `joint`, `strap`,
/// `scenario`, `scenario_joint`), `unit` and `meaning`; a key absent from an output is `None`.
pub fn trace_columns(py: Python<'_>) -> PyResult<Bound<'_, PyList>> {
    let out = PyList::empty(py);
    for c in &TRACE_COLUMNS {
        let d = PyDict::new(py);
        d.set_item("python", c.python)?;
        d.set_item("csv", c.csv)?;
        let per = match c.per {
            Per::Step => "step",
            Per::Joint => "joint",
            Per::Strap => "strap",
            Per::Scenario => "scenario",
            Per::ScenarioJoint => "scenario_joint",
        };
        d.set_item("per", per)?;
        d.set_item("unit", c.unit)?;
        d.set_item("meaning", c.meaning)?;
        out.append(d)?;
    }
    Ok(out)
}

/// A TOML value as the matching Python object.
pub fn toml_to_py<'py>(py: Python<'py>, v: &toml::Value) -> PyResult<Bound<'py, PyAny>> {
    Ok(match v {
        toml::Value::String(s) => PyString::new(py, s).into_any(),
        toml::Value::Integer(i) => i.into_pyobject(py)?.into_any(),
        toml::Value::Float(f) => PyFloat::new(py, *f).into_any(),
        toml::Value::Boolean(b) => PyBool::new(py, *b).to_owned().into_any(),
        toml::Value::Datetime(d) => PyString::new(py, &d.to_string()).into_any(),
        toml::Value::Array(a) => {
            let items = a
                .iter()
                .map(|x| toml_to_py(py, x))
                .collect::<PyResult<Vec<_>>>()?;
            PyList::new(py, items)?.into_any()
        }
        toml::Value::Table(t) => {
            let d = PyDict::new(py);
            for (k, x) in t {
                d.set_item(k, toml_to_py(py, x)?)?;
            }
            d.into_any()
        }
    })
}

/// Deepest nesting of lists and dicts accepted as a key's value (scenario values nest at most
/// two levels; the limit keeps a deeply nested argument from overflowing the stack).
const MAX_DEPTH: usize = 16;

/// A Python value as TOML, for setting a scenario key. Strings go through
/// [`exompc_study::io::parse_value`] exactly as a value typed on the command line.
pub fn py_to_toml(key: &str, v: &Bound<'_, PyAny>) -> PyResult<toml::Value> {
    to_toml_at(key, v, 0)
}

fn to_toml_at(key: &str, v: &Bound<'_, PyAny>, depth: usize) -> PyResult<toml::Value> {
    if depth > MAX_DEPTH {
        return Err(crate::ConfigError::new_err(format!(
            "invalid value for {key}: nested deeper than {MAX_DEPTH} levels"
        )));
    }
    if v.is_instance_of::<PyBool>() {
        return Ok(toml::Value::Boolean(v.extract()?));
    }
    if v.is_instance_of::<PyInt>() {
        return Ok(toml::Value::Integer(v.extract().map_err(|_| {
            crate::ConfigError::new_err(format!("invalid value for {key}: integer out of range"))
        })?));
    }
    if v.is_instance_of::<PyFloat>() {
        return Ok(toml::Value::Float(v.extract()?));
    }
    if let Ok(s) = v.cast::<PyString>() {
        return Ok(exompc_study::io::parse_value(&s.to_cow()?));
    }
    if let Ok(d) = v.cast::<PyDict>() {
        let mut t = toml::Table::new();
        for (k, x) in d.iter() {
            let k: String = k.extract()?;
            let sub = format!("{key}.{k}");
            t.insert(k, to_toml_at(&sub, &x, depth + 1)?);
        }
        return Ok(toml::Value::Table(t));
    }
    if v.is_instance_of::<PyList>() || v.is_instance_of::<PyTuple>() {
        let items = v
            .try_iter()?
            .enumerate()
            .map(|(i, x)| to_toml_at(&format!("{key}[{i}]"), &x?, depth + 1))
            .collect::<PyResult<Vec<_>>>()?;
        return Ok(toml::Value::Array(items));
    }
    if v.is_instance_of::<PyUntypedArray>() {
        return to_toml_at(key, &v.call_method0("tolist")?, depth + 1);
    }
    // numpy scalars and other number-likes.
    if v.hasattr("__index__")? {
        if let Ok(i) = v.call_method0("__index__")?.extract::<i64>() {
            return Ok(toml::Value::Integer(i));
        }
    }
    if v.hasattr("__float__")? {
        return Ok(toml::Value::Float(v.call_method0("__float__")?.extract()?));
    }
    Err(crate::ConfigError::new_err(format!(
        "invalid value for {key}: cannot use a {} (expected a number, bool, string or list)",
        v.get_type().name()?
    )))
}

/// Reads a length-`N` float vector argument named `name`: a float64 numpy array of shape
/// `(N,)`, a list/tuple of `N` numbers, or (for `N == 1`) a number. Anything else raises a
/// `TypeError` (wrong dtype or type) or `ValueError` (wrong shape) naming the argument.
pub fn vector<const N: usize>(name: &str, v: &Bound<'_, PyAny>) -> PyResult<SVector<f64, N>> {
    let mut out = SVector::<f64, N>::zeros();
    if let Ok(arr) = v.cast::<PyUntypedArray>() {
        let py = v.py();
        if !arr.dtype().is_equiv_to(&numpy::dtype::<f64>(py)) {
            return Err(PyTypeError::new_err(format!(
                "{name}: expected a float64 array, got dtype {}",
                arr.dtype().str()?
            )));
        }
        if arr.shape() != [N] {
            return Err(PyValueError::new_err(format!(
                "{name}: expected shape ({N},), got {}",
                shape(arr.shape())
            )));
        }
        let a = arr
            .cast::<PyArray1<f64>>()?
            .try_readonly()
            .map_err(|e| PyValueError::new_err(format!("{name}: cannot read the array ({e})")))?;
        for (o, x) in out.iter_mut().zip(a.as_array().iter()) {
            *o = *x;
        }
        return Ok(out);
    }
    if N == 1 && (v.is_instance_of::<PyFloat>() || v.is_instance_of::<PyInt>()) {
        out[0] = v.extract()?;
        return Ok(out);
    }
    if v.is_instance_of::<PyList>() || v.is_instance_of::<PyTuple>() {
        let len = v.len()?;
        if len != N {
            return Err(PyValueError::new_err(format!(
                "{name}: expected {N} values, got {len}"
            )));
        }
        for (i, x) in v.try_iter()?.enumerate() {
            let x = x?;
            if x.is_instance_of::<PyBool>()
                || !(x.is_instance_of::<PyFloat>() || x.is_instance_of::<PyInt>())
            {
                return Err(PyTypeError::new_err(format!(
                    "{name}[{i}]: expected a number, got {}",
                    x.get_type().name()?
                )));
            }
            out[i] = x.extract()?;
        }
        return Ok(out);
    }
    Err(PyTypeError::new_err(format!(
        "{name}: expected a float64 numpy array of shape ({N},) or a list of {N} numbers, got {}",
        v.get_type().name()?
    )))
}

/// Writes `v` into `out`, a writable float64 array of shape `(N,)`.
pub fn write_into<const N: usize>(out: &Bound<'_, PyAny>, v: &SVector<f64, N>) -> PyResult<()> {
    let arr = out.cast::<PyArray1<f64>>().map_err(|_| {
        PyTypeError::new_err(format!(
            "out: expected a float64 numpy array of shape ({N},)"
        ))
    })?;
    if arr.shape() != [N] {
        return Err(PyValueError::new_err(format!(
            "out: expected shape ({N},), got {}",
            shape(arr.shape())
        )));
    }
    let mut w = arr.try_readwrite().map_err(|e| {
        PyValueError::new_err(format!(
            "out: cannot write into the array: {e} (pass a writeable float64 array, or no out=)"
        ))
    })?;
    for (o, x) in w.as_array_mut().iter_mut().zip(v.iter()) {
        *o = *x;
    }
    Ok(())
}

/// `v` as a new float64 numpy array.
pub fn array<'py, const N: usize>(
    py: Python<'py>,
    v: &SVector<f64, N>,
) -> Bound<'py, PyArray1<f64>> {
    PyArray1::from_slice(py, v.as_slice())
}

/// A numpy shape as Python prints it: `(3,)`, `(2, 2)`.
fn shape(s: &[usize]) -> String {
    match s {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            s.iter()
                .map(usize::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}
