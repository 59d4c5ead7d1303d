//! Python keywords as the library's settings keywords: each value becomes JSON and the library's
//! one reader (`nis::integrate::Settings::with_keywords`, the reader of the C ABI's JSON and the
//! CLI's flags too) places and checks it, so its errors name the keyword.

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};
use serde_json::{Map, Value};

/// The keyword arguments as (name, JSON value) pairs, in the order given; a keyword given as
/// None is left out (its setting keeps the default).
pub(crate) fn keywords(given: Option<&Bound<'_, PyDict>>) -> PyResult<Vec<(String, Value)>> {
    let mut out = Vec::new();
    for (k, v) in given.into_iter().flat_map(|d| d.iter()) {
        let name: String = k.extract()?;
        if !v.is_none() {
            let value = json_of(&v, &name)?;
            out.push((name, value));
        }
    }
    Ok(out)
}

/// A Python value as JSON: None, bool, int, finite float, str, and lists, tuples and dicts (str
/// keys) of them. `name` names the keyword in errors.
pub(crate) fn json_of(v: &Bound<'_, PyAny>, name: &str) -> PyResult<Value> {
    if v.is_none() {
        return Ok(Value::Null);
    }
    if let Ok(b) = v.cast::<PyBool>() {
        return Ok(Value::Bool(b.is_true()));
    }
    if v.is_instance_of::<PyInt>() {
        if let Ok(i) = v.extract::<i64>() {
            return Ok(Value::from(i));
        }
        if let Ok(u) = v.extract::<u64>() {
            return Ok(Value::from(u));
        }
        return Err(PyValueError::new_err(format!(
            "{name}: the integer {v} is out of range"
        )));
    }
    // numpy's integers are not Python ints, but index like them.
    if !v.is_instance_of::<PyFloat>() {
        if let Ok(i) = v.extract::<i64>() {
            return Ok(Value::from(i));
        }
    }
    if v.is_instance_of::<PyFloat>()
        || !v.is_instance_of::<PyString>() && v.extract::<f64>().is_ok()
    {
        let x: f64 = v.extract()?;
        return serde_json::Number::from_f64(x)
            .map(Value::Number)
            .ok_or_else(|| PyValueError::new_err(format!("{name} must be finite, got {x}")));
    }
    if let Ok(s) = v.cast::<PyString>() {
        return Ok(Value::String(s.extract::<String>()?));
    }
    if v.is_instance_of::<PyList>() || v.is_instance_of::<PyTuple>() {
        return v
            .try_iter()?
            .map(|item| json_of(&item?, name))
            .collect::<PyResult<Vec<Value>>>()
            .map(Value::Array);
    }
    if let Ok(d) = v.cast::<PyDict>() {
        let mut fields = Map::new();
        for (k, item) in d.iter() {
            let key: String = k.extract().map_err(|_| {
                PyValueError::new_err(format!("{name}: the keys of a dict must be str"))
            })?;
            let inner = format!("{name}[{key:?}]");
            fields.insert(key, json_of(&item, &inner)?);
        }
        return Ok(Value::Object(fields));
    }
    Err(PyValueError::new_err(format!(
        "{name}: a {} is not a setting's value (bool, int, float, str, list or dict)",
        v.get_type().name()?
    )))
}

/// The settings keywords `nis.Integrator` takes (for any method), sorted: the list the stub
/// `_nis.pyi` is checked against (tests/test_stub.py).
#[pyfunction]
pub(crate) fn _keywords() -> Vec<String> {
    nis::integrate::settings::keyword_names()
}
