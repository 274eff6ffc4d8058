//! What both plugin registries share: plugin specs (`name[:argument]`), their options, and
//! the sorted, duplicate-free view of an `inventory` registry.

use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;

use crate::{Error, Result};

/// One option a plugin accepts in its argument (`name:key=value,key=value`).
#[derive(Clone, Copy, Debug)]
pub struct PluginOption {
    pub key: &'static str,
    pub default: &'static str,
    pub help: &'static str,
}

/// A plugin named on the command line or in a configuration: `name` or `name:argument`.
/// The argument is the plugin's own business: a path for `onnx`, `key=value` options for most.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct PluginSpec {
    pub name: String,
    pub argument: Option<String>,
}

impl PluginSpec {
    pub fn new(name: impl Into<String>) -> Self {
        PluginSpec {
            name: name.into(),
            argument: None,
        }
    }
}

impl FromStr for PluginSpec {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        let (name, argument) = match s.split_once(':') {
            Some((n, a)) => (n, Some(a.to_string())),
            None => (s, None),
        };
        if name.is_empty() {
            return Err(Error::Invalid(format!("'{s}' names no plugin")));
        }
        Ok(PluginSpec {
            name: name.to_string(),
            argument,
        })
    }
}

impl fmt::Display for PluginSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.argument {
            Some(a) => write!(f, "{}:{a}", self.name),
            None => f.write_str(&self.name),
        }
    }
}

/// Parses a `key=value,key=value` argument against the options a plugin declares, filling in
/// defaults. Unknown keys and malformed pairs are errors that list the valid keys.
pub fn parse_options(
    plugin: &str,
    argument: Option<&str>,
    declared: &[PluginOption],
) -> Result<BTreeMap<&'static str, String>> {
    let mut values: BTreeMap<&'static str, String> = declared
        .iter()
        .map(|o| (o.key, o.default.to_string()))
        .collect();
    let valid = || {
        if declared.is_empty() {
            "it takes no options".to_string()
        } else {
            let keys: Vec<_> = declared.iter().map(|o| o.key).collect();
            format!("valid options: {}", keys.join(", "))
        }
    };
    for pair in argument.unwrap_or("").split(',').filter(|p| !p.is_empty()) {
        let Some((key, value)) = pair.split_once('=') else {
            return Err(Error::Plugin {
                plugin: plugin.to_string(),
                message: format!("option '{pair}' is not key=value; {}", valid()),
            });
        };
        let Some(option) = declared.iter().find(|o| o.key == key.trim()) else {
            return Err(Error::Plugin {
                plugin: plugin.to_string(),
                message: format!("unknown option '{key}'; {}", valid()),
            });
        };
        values.insert(option.key, value.trim().to_string());
    }
    Ok(values)
}

/// Parses one option value, naming the plugin and the key when it is malformed.
pub fn option_value<T: FromStr>(
    plugin: &str,
    options: &BTreeMap<&'static str, String>,
    key: &str,
) -> Result<T> {
    let raw = options.get(key).map(String::as_str).unwrap_or("");
    raw.parse().map_err(|_| Error::Plugin {
        plugin: plugin.to_string(),
        message: format!("option {key}='{raw}' is not a valid value"),
    })
}

/// What every registration struct exposes to the shared registry code.
pub trait Registration: Sync + 'static {
    fn name(&self) -> &'static str;
}

/// The registrations of one kind, sorted by name (inventory's order is not guaranteed),
/// rejecting a name registered twice.
pub(crate) fn sorted_registry<R: Registration>(
    kind: &'static str,
    registrations: impl Iterator<Item = &'static R>,
) -> Result<Vec<&'static R>> {
    let mut all: Vec<&'static R> = registrations.collect();
    all.sort_by_key(|r| r.name());
    if let Some(pair) = all.windows(2).find(|w| w[0].name() == w[1].name()) {
        return Err(Error::DuplicatePlugin {
            kind,
            name: pair[0].name().to_string(),
        });
    }
    Ok(all)
}

/// Finds a registration by name, or says which names exist.
pub(crate) fn find_registration<R: Registration>(
    kind: &'static str,
    registry: Vec<&'static R>,
    name: &str,
) -> Result<&'static R> {
    registry
        .iter()
        .find(|r| r.name() == name)
        .copied()
        .ok_or_else(|| Error::UnknownPlugin {
            kind,
            name: name.to_string(),
            known: registry.iter().map(|r| r.name().to_string()).collect(),
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    const OPTS: &[PluginOption] = &[PluginOption {
        key: "a",
        default: "-0.5",
        help: "",
    }];

    #[test]
    fn spec_parses_name_and_argument() {
        let s: PluginSpec = "onnx:models/x.onnx".parse().unwrap();
        assert_eq!(s.name, "onnx");
        assert_eq!(s.argument.as_deref(), Some("models/x.onnx"));
        assert_eq!(s.to_string(), "onnx:models/x.onnx");
        assert!("".parse::<PluginSpec>().is_err());
    }

    #[test]
    fn options_fill_defaults_and_reject_unknown_keys() {
        let o = parse_options("bicubic", None, OPTS).unwrap();
        assert_eq!(option_value::<f32>("bicubic", &o, "a").unwrap(), -0.5);
        let o = parse_options("bicubic", Some("a=-0.75"), OPTS).unwrap();
        assert_eq!(option_value::<f32>("bicubic", &o, "a").unwrap(), -0.75);
        let e = parse_options("bicubic", Some("b=1"), OPTS).unwrap_err();
        assert!(e.to_string().contains("valid options: a"), "{e}");
        let e = parse_options("bicubic", Some("a=x"), OPTS).unwrap();
        assert!(option_value::<f32>("bicubic", &e, "a").is_err());
    }
}
