//! Keyword parameters and configurations: Python values to the library's serde configurations,
//! with the same names and defaults as the TOML files (`configs/*.toml`).

use crate::errors::{config, pipeline};
use flowfilter_pipeline::PipelineConfig;
use flowfilter_pipeline::registration::RegistrationConfig;
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};
use serde_json::{Map, Value};
use std::path::PathBuf;

/// A Python value as JSON: None, bool, int, float, str, lists/tuples and dicts of them (keys
/// are strings). `key` names the value in errors. `None` inside a dict drops the key (the
/// default applies).
pub fn to_json(obj: &Bound<'_, PyAny>, key: &str) -> PyResult<Value> {
    if obj.is_none() {
        return Ok(Value::Null);
    }
    // NumPy arrays and scalars: their Python values.
    if obj.hasattr("tolist")? && !obj.is_instance_of::<PyList>() {
        return to_json(&obj.call_method0("tolist")?, key);
    }
    if obj.is_instance_of::<PyBool>() {
        return Ok(Value::Bool(obj.extract()?));
    }
    // NumPy's integer and float scalars have `__index__` and `__float__`.
    if obj.is_instance_of::<PyInt>() || obj.hasattr("__index__")? {
        return Ok(match obj.extract::<i64>() {
            Ok(v) => Value::from(v),
            Err(_) => Value::from(obj.extract::<u64>().map_err(|_| config(format!("{key}: integer out of range")))?),
        });
    }
    if obj.is_instance_of::<PyFloat>() || obj.hasattr("__float__")? {
        let v: f64 = obj.extract().map_err(|_| config(format!("{key}: expected a number")))?;
        return serde_json::Number::from_f64(v)
            .map(Value::Number)
            .ok_or_else(|| config(format!("{key}: must be finite, found {v}")));
    }
    if let Ok(s) = obj.cast::<PyString>() {
        return Ok(Value::String(s.to_cow()?.into_owned()));
    }
    if let Ok(d) = obj.cast::<PyDict>() {
        return dict_to_json(d, key).map(Value::Object);
    }
    if obj.is_instance_of::<PyList>() || obj.is_instance_of::<PyTuple>() {
        let items = obj.try_iter()?.enumerate().map(|(i, item)| to_json(&item?, &format!("{key}[{i}]")));
        return items.collect::<PyResult<Vec<_>>>().map(Value::Array);
    }
    let found = obj.get_type().name().map_or_else(|_| "?".into(), |n| n.to_string());
    Err(config(format!("{key}: unsupported value of type {found} (expected a number, bool, str, list or dict)")))
}

/// A dict with string keys as a JSON object; keys whose value is `None` are left out.
pub fn dict_to_json(d: &Bound<'_, PyDict>, key: &str) -> PyResult<Map<String, Value>> {
    let mut map = Map::new();
    for (k, v) in d.iter() {
        let name: String = k.extract().map_err(|_| config(format!("{key}: keys must be strings")))?;
        let path = if key.is_empty() { name.clone() } else { format!("{key}.{name}") };
        let value = to_json(&v, &path)?;
        if !value.is_null() {
            map.insert(name, value);
        }
    }
    Ok(map)
}

/// The TOML table of the backend `method` names (`icp`, `cpd`, `filterreg`, `flowfilter`).
fn backend_table(method: &str) -> PyResult<&'static str> {
    Ok(match method {
        "icp" | "icp-pt2pt" | "icp-pt2pl" => "icp",
        "cpd" => "cpd",
        "filterreg" | "filterreg-pt2pt" | "filterreg-pt2pl" => "filterreg",
        m if m.starts_with("flowfilter") => "flowfilter",
        other => {
            return Err(config(format!(
                "unknown method '{other}' (available: {})",
                flowfilter_pipeline::registration::METHOD_NAMES.join(", ")
            )));
        }
    })
}

/// Keys of the backends' tables that the method name sets.
const SET_BY_METHOD: [&str; 2] = ["variant", "mode"];

/// The registration configuration with `params` as the keys of `method`'s table (the
/// `[registration.<table>]` keys of a pipeline configuration).
pub fn registration_config(method: &str, params: Option<&Bound<'_, PyDict>>) -> PyResult<RegistrationConfig> {
    let table = backend_table(method)?;
    let Some(params) = params else { return Ok(RegistrationConfig::default()) };
    let params = dict_to_json(params, "")?;
    if let Some(key) = SET_BY_METHOD.iter().find(|k| params.contains_key(**k)) {
        return Err(config(format!("{key}: set by the method name ('{method}'); choose the method instead")));
    }
    let parse = |params: Map<String, Value>| {
        let mut root = Map::new();
        root.insert(table.into(), Value::Object(params));
        serde_json::from_value::<RegistrationConfig>(Value::Object(root))
    };
    parse(params.clone()).map_err(|e| {
        // serde's message does not name the key: the first key that fails alone does.
        let key = params.iter().find(|(k, v)| parse(Map::from_iter([((*k).clone(), (*v).clone())])).is_err());
        match key {
            Some((k, v)) => config(format!("method '{method}': parameter {k} = {v}: {e}")),
            None => config(format!("method '{method}': parameters of [{table}]: {e}")),
        }
    })
}

/// The defaults of `method`'s parameters, as a dict of the names `register` takes.
pub fn default_params(method: &str) -> PyResult<Value> {
    let table = backend_table(method)?;
    let all = serde_json::to_value(RegistrationConfig::default()).map_err(|e| config(e.to_string()))?;
    let mut params = all[table].clone();
    if let Value::Object(map) = &mut params {
        map.retain(|k, _| !SET_BY_METHOD.contains(&k.as_str()));
    }
    Ok(params)
}

/// A pipeline configuration: `None` (the defaults), a path to a TOML file, or a dict of the
/// same tables and keys.
pub fn pipeline_config(obj: Option<&Bound<'_, PyAny>>) -> PyResult<PipelineConfig> {
    let Some(obj) = obj.filter(|o| !o.is_none()) else { return Ok(PipelineConfig::default()) };
    if let Ok(d) = obj.cast::<PyDict>() {
        let value = Value::Object(dict_to_json(d, "config")?);
        let parsed: PipelineConfig = serde_json::from_value(value).map_err(|e| config(format!("config: {e}")))?;
        parsed.validate().map_err(|e| config(format!("config: {e}")))?;
        return Ok(parsed);
    }
    let path: PathBuf = obj
        .extract()
        .map_err(|_| config("config: expected a path to a TOML file (str or os.PathLike) or a dict of its tables"))?;
    PipelineConfig::from_file(&path).map_err(|e| pipeline(&e))
}
