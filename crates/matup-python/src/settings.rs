//! A run's settings from Python keywords: the TOML keys, by their names alone where a name is
//! one key (`self_ensemble`, `epochs`, `window`) or by section (`filter={"window": 9}`), over
//! matup's defaults. The merged table goes through `Config::from_toml`, so Python gets the
//! CLI's validation and messages, and no list of settings is kept here.

use pyo3::prelude::*;
use toml::{Table, Value};

use matup::method::Config;

use crate::network::RunNetworks;

use crate::exception;

/// `settings` (a JSON object) over the defaults; the registered networks' specs as the
/// upsampler and in place of matup's networks.
pub fn config(py: Python<'_>, settings: &str, networks: &RunNetworks) -> PyResult<Config> {
    let bad = |m: String| exception(py, "InvalidInput", m);
    let given: serde_json::Map<String, serde_json::Value> =
        serde_json::from_str(settings).map_err(|e| bad(format!("settings: {e}")))?;
    let mut table = Table::try_from(Config::default()).map_err(|e| bad(e.to_string()))?;
    for (key, value) in given {
        set(&mut table, &key, value).map_err(bad)?;
    }
    if let Some(registered) = &networks.upsampler {
        table.insert("upsampler".into(), Value::String(registered.spec()));
    }
    if !networks.instead.is_empty() {
        let instead: Table = (networks.instead.iter())
            .map(|(name, registered)| (name.clone(), Value::String(registered.spec())))
            .collect();
        table.insert("networks".into(), Value::Table(instead));
    }
    let text = toml::to_string(&table).map_err(|e| bad(e.to_string()))?;
    Config::from_toml(&text, "settings").map_err(|e| crate::to_python(py, &e))
}

/// Sets `key` in `table`: a top-level key or section, or the one section's key of that name.
fn set(table: &mut Table, key: &str, value: serde_json::Value) -> Result<(), String> {
    if value.is_null() {
        // None: the default ("auto" for tileable, which TOML spells so).
        if key == "tileable" {
            table.insert(key.into(), Value::String("auto".into()));
        }
        return Ok(());
    }
    let sections: Vec<String> = (table.iter())
        .filter(|(_, v)| v.as_table().is_some_and(|t| t.contains_key(key)))
        .map(|(k, _)| k.clone())
        .collect();
    let value = toml_value(key, value)?;
    match (table.get_mut(key), &sections[..]) {
        (Some(Value::Table(section)), _) => match value {
            Value::Table(given) => {
                for (k, v) in given {
                    section.insert(k, v);
                }
                Ok(())
            }
            _ => Err(format!(
                "'{key}' is a section: give it a dict of its settings"
            )),
        },
        (Some(slot), _) => {
            *slot = value;
            Ok(())
        }
        (None, [section]) => {
            let t = table[section.as_str()]
                .as_table_mut()
                .expect("found as a table");
            t.insert(key.into(), value);
            Ok(())
        }
        (None, []) => {
            // A setting whose default is unset (train.texels_per_epoch) is not in the table:
            // set at the top, it is refused by name unless it belongs there.
            table.insert(key.into(), value);
            Ok(())
        }
        (None, several) => Err(format!(
            "'{key}' is a setting of several sections ({}): give it as section={{'{key}': …}}",
            several.join(", ")
        )),
    }
}

/// A JSON value as TOML (which has no null: a None inside a section is left out).
fn toml_value(key: &str, value: serde_json::Value) -> Result<Value, String> {
    use serde_json::Value as J;
    Ok(match value {
        J::Bool(b) => Value::Boolean(b),
        J::Number(n) => match n.as_i64() {
            Some(i) => Value::Integer(i),
            None => Value::Float(n.as_f64().ok_or(format!("{key}: {n} is not a number"))?),
        },
        J::String(s) => Value::String(s),
        J::Array(items) => Value::Array(
            (items.into_iter())
                .map(|v| toml_value(key, v))
                .collect::<Result<_, _>>()?,
        ),
        J::Object(fields) => Value::Table(
            (fields.into_iter())
                .filter(|(_, v)| !v.is_null())
                .map(|(k, v)| Ok((k.clone(), toml_value(&k, v)?)))
                .collect::<Result<_, String>>()?,
        ),
        J::Null => return Err(format!("{key}: None has no TOML value")),
    })
}
