//! From text and JSON to typed options, with errors that name the method, the option and what
//! is allowed.

use serde_json::{Map, Value};

use super::{Estimator, EstimatorOptions, Labelled, Method};
use crate::{Error, Result};

/// An [`Error::EstimatorOption`] of `method`.
fn option_error(method: Method, option: &str, reason: impl Into<String>) -> Error {
    Error::EstimatorOption { method: method.name().into(), option: option.into(), reason: reason.into() }
}

/// An error of an options type's `validate` as an error of `method`'s options.
pub(super) fn named(method: Method, e: Error) -> Error {
    match e {
        Error::InvalidOption { name, reason } => option_error(method, &name, reason),
        other => other,
    }
}

/// The option names of `T`: the keys of its defaults written as JSON.
pub(super) fn option_names<T: EstimatorOptions>() -> Vec<String> {
    match serde_json::to_value(T::default()) {
        Ok(Value::Object(map)) => map.keys().cloned().collect(),
        _ => Vec::new(),
    }
}

/// serde's message without its trailing position.
fn message(e: &serde_json::Error) -> String {
    let text = e.to_string();
    match text.rfind(" at line ") {
        Some(i) => text[..i].to_string(),
        None => text,
    }
}

/// The options `T` of `method` from `options`: every key must be an option of `T`; the values
/// are deserialised (the first key whose value `T` rejects is named) and validated.
pub(super) fn typed<T: EstimatorOptions>(method: Method, options: &Map<String, Value>) -> Result<T> {
    let known = option_names::<T>();
    if let Some(key) = options.keys().find(|k| !known.contains(k)) {
        let names = if known.is_empty() { "none".to_string() } else { known.join(", ") };
        return Err(option_error(
            method,
            key,
            format!("`{method}` has no such option (its options: {names})"),
        ));
    }
    let value: T = match serde_json::from_value(Value::Object(options.clone())) {
        Ok(v) => v,
        Err(e) => {
            let key = options
                .iter()
                .find(|(k, v)| {
                    let single: Map<String, Value> = [((*k).clone(), (*v).clone())].into_iter().collect();
                    serde_json::from_value::<T>(Value::Object(single)).is_err()
                })
                .map_or_else(|| "options".to_string(), |(k, _)| k.clone());
            return Err(option_error(method, &key, message(&e)));
        }
    };
    value.validate().map_err(|e| named(method, e))?;
    Ok(value)
}

/// A command-line value: a boolean, an integer, a number, a list of numbers `a;b;c`, a JSON
/// array (`[-3,3]`, `[[-3,3],[-4,4]]`), or text.
fn value_of(text: &str) -> Value {
    let t = text.trim();
    if t.starts_with('[') {
        if let Ok(list @ Value::Array(_)) = serde_json::from_str::<Value>(t) {
            return list;
        }
    }
    if let Ok(b) = t.parse::<bool>() {
        return Value::Bool(b);
    }
    if let Ok(i) = t.parse::<i64>() {
        return Value::from(i);
    }
    if let Ok(x) = t.parse::<f64>() {
        if x.is_finite() {
            return Value::from(x);
        }
    }
    if t.contains(';') && !t.contains('=') {
        let parts: Vec<Option<f64>> = t.split(';').map(|p| p.trim().parse::<f64>().ok()).collect();
        if parts.iter().all(Option::is_some) {
            return Value::Array(parts.into_iter().flatten().map(Value::from).collect());
        }
    }
    Value::String(t.to_string())
}

/// Options from `NAME=VALUE` pairs as given on the command line: a dotted name is a nested
/// option (`dual.max_iterations=100`), a value is typed by its text (see `value_of`). Errors: a
/// name given twice or both as a value and as a table.
pub fn options_from_pairs<I, K, V>(pairs: I) -> Result<Map<String, Value>>
where
    I: IntoIterator<Item = (K, V)>,
    K: AsRef<str>,
    V: AsRef<str>,
{
    let mut map = Map::new();
    for (name, text) in pairs {
        let name = name.as_ref().trim();
        let parts: Vec<&str> = name.split('.').collect();
        if parts.iter().any(|p| p.is_empty()) {
            return Err(Error::InvalidOption { name: name.into(), reason: "is not an option name".into() });
        }
        let mut table = &mut map;
        for part in &parts[..parts.len() - 1] {
            let entry = table.entry(part.to_string()).or_insert_with(|| Value::Object(Map::new()));
            table = match entry {
                Value::Object(t) => t,
                _ => {
                    return Err(Error::InvalidOption {
                        name: name.into(),
                        reason: format!("`{part}` is given both as a value and as a table"),
                    })
                }
            };
        }
        let last = parts[parts.len() - 1];
        if table.insert(last.to_string(), value_of(text.as_ref())).is_some() {
            return Err(Error::InvalidOption { name: name.into(), reason: "is given twice".into() });
        }
    }
    Ok(map)
}

/// The rule of `onsager estimate` and the Python package for the initial guess of the
/// path-space MAP methods: for `jme` and `mee`, the parameters whose values the user set
/// (`set`, by name) are kept as the initial guess, i.e. `keep_initial = set`, unless the
/// options already name `keep_initial`. Other methods' options are left unchanged.
pub fn keep_set_parameters(method: Method, options: &mut Map<String, Value>, set: &[String]) {
    if matches!(method, Method::Jme | Method::Mee) && !set.is_empty() && !options.contains_key("keep_initial")
    {
        options.insert("keep_initial".into(), Value::from(set.to_vec()));
    }
}

/// Splits `text` at the commas outside double quotes, removing the quotes.
fn split_top(text: &str) -> Result<Vec<String>> {
    let (mut parts, mut current, mut quoted) = (Vec::new(), String::new(), false);
    for c in text.chars() {
        match c {
            '"' => quoted = !quoted,
            ',' if !quoted => parts.push(std::mem::take(&mut current)),
            _ => current.push(c),
        }
    }
    if quoted {
        return Err(Error::InvalidOption {
            name: "methods".into(),
            reason: format!("unclosed quote in `{text}`"),
        });
    }
    parts.push(current);
    Ok(parts)
}

/// Parses a list of estimators written `METHOD[:NAME=VALUE,…],METHOD…`: an item without `=`
/// or with a `:` before its first `=` starts a new estimator, any other item is an option of
/// the current one (so `exp-closure:moments=6,panels=16,jme:transcription=trapezoidal,uks`
/// is three estimators); a value with commas goes in double quotes
/// (`ksp:grid="lo=-3,hi=3,cells=200"`). The option `label` names the estimator's results;
/// by default the method's name, or, when two estimators have the same method, the text that
/// describes each.
///
/// Errors: an empty item, an unknown method, a bad option ([`Error::EstimatorOption`]), two
/// estimators with the same label.
pub fn parse_list(text: &str) -> Result<Vec<Labelled>> {
    // (method text, option pairs, the text of the whole item)
    let mut items: Vec<Item> = Vec::new();
    for part in split_top(text)? {
        let p = part.trim();
        if p.is_empty() {
            return Err(Error::InvalidOption {
                name: "methods".into(),
                reason: format!("an empty item in `{text}`"),
            });
        }
        let colon = p.find(':');
        let starts = match (colon, p.find('=')) {
            (_, None) => true,
            (Some(c), Some(e)) => c < e,
            (None, Some(_)) => false,
        };
        if starts {
            let (method, first) = match colon {
                Some(c) => (&p[..c], Some(&p[c + 1..])),
                None => (p, None),
            };
            items.push((method.trim().to_string(), Vec::new(), p.to_string()));
            if let Some(first) = first.filter(|f| !f.trim().is_empty()) {
                let last = items.last_mut().expect("just pushed");
                last.1.push(pair(first)?);
            }
        } else {
            let Some(last) = items.last_mut() else {
                return Err(Error::InvalidOption {
                    name: "methods".into(),
                    reason: format!("`{p}` comes before any method"),
                });
            };
            last.1.push(pair(p)?);
            last.2.push(',');
            last.2.push_str(p);
        }
    }
    let mut out: Vec<Labelled> = Vec::with_capacity(items.len());
    let methods: Vec<String> = items.iter().map(|i| i.0.clone()).collect();
    for (method, pairs, whole) in items {
        let m: Method = method.parse()?;
        let (labels, options): (Vec<_>, Vec<_>) = pairs.into_iter().partition(|(k, _)| k == "label");
        let estimator = Estimator::from_options(m, &options_from_pairs(options)?)?;
        let label = match labels.into_iter().last() {
            Some((_, l)) => l,
            None if methods.iter().filter(|x| **x == method).count() > 1 => whole,
            None => m.name().to_string(),
        };
        if out.iter().any(|o| o.label == label) {
            return Err(Error::InvalidOption {
                name: "methods".into(),
                reason: format!("two estimators are labelled `{label}`; give one a `label=…`"),
            });
        }
        out.push(Labelled { label, estimator });
    }
    Ok(out)
}

/// One estimator of a list as written: its method, its `NAME=VALUE` pairs and its text.
type Item = (String, Vec<(String, String)>, String);

fn pair(item: &str) -> Result<(String, String)> {
    match item.split_once('=') {
        Some((k, v)) if !k.trim().is_empty() => Ok((k.trim().to_string(), v.trim().to_string())),
        _ => Err(Error::InvalidOption {
            name: "methods".into(),
            reason: format!("expected NAME=VALUE, got `{item}`"),
        }),
    }
}

/// An estimator as written in a file: `method`, optional `label` and `options`.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Entry {
    method: Method,
    label: Option<String>,
    #[serde(default)]
    options: Map<String, Value>,
}

/// The list of a file: `[[estimators]]` tables in TOML, `{"estimators": [...]}` in JSON.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct List {
    estimators: Vec<Entry>,
}

/// Reads a list of estimators from a TOML file (`[[estimators]]` tables with `method`, an
/// optional `label` and `options = { … }`, as in the experiment specs) or, for a `.json` file,
/// from `{"estimators": [{"method": …, "label": …, "options": {…}}]}`.
///
/// Errors: the file cannot be read or parsed ([`Error::Data`] with the parser's message); an
/// unknown method or a bad option ([`Error::InvalidOption`] named
/// `estimators.LABEL.options.NAME`); two estimators with the same label.
pub fn read_list(path: &std::path::Path) -> Result<Vec<Labelled>> {
    let text =
        std::fs::read_to_string(path).map_err(|source| Error::Io { path: path.to_path_buf(), source })?;
    let data_error = |reason: String| Error::Data { path: path.to_path_buf(), line: 0, column: None, reason };
    let json = path.extension().is_some_and(|e| e == "json");
    let value: Value = if json {
        serde_json::from_str(&text).map_err(|e| data_error(e.to_string()))?
    } else {
        let table: toml::Table =
            toml::from_str(&text).map_err(|e| data_error(e.to_string().trim_end().to_string()))?;
        serde_json::to_value(table).map_err(|e| data_error(e.to_string()))?
    };
    list_from_value(value, path)
}

/// A list of estimators from its JSON value, `{"estimators": [{"method": …, "label": …,
/// "options": {…}}]}` (the form [`read_list`] reads; the Python package builds it from a list
/// of dicts); `source` names it in error messages. Errors: as [`read_list`].
pub fn list_from_json(value: Value, source: &str) -> Result<Vec<Labelled>> {
    list_from_value(value, std::path::Path::new(source))
}

fn list_from_value(value: Value, path: &std::path::Path) -> Result<Vec<Labelled>> {
    let data_error = |reason: String| Error::Data { path: path.to_path_buf(), line: 0, column: None, reason };
    let list: List = serde_json::from_value(value).map_err(|e| data_error(message(&e)))?;
    let mut out: Vec<Labelled> = Vec::with_capacity(list.estimators.len());
    for entry in list.estimators {
        let label = entry.label.unwrap_or_else(|| entry.method.name().to_string());
        let estimator = Estimator::from_options(entry.method, &entry.options).map_err(|e| match e {
            Error::EstimatorOption { method, option, reason } => Error::InvalidOption {
                name: format!("estimators.{label}.options.{option}"),
                reason: format!("{reason} (`{method}`, {})", path.display()),
            },
            other => other,
        })?;
        if out.iter().any(|o| o.label == label) {
            return Err(Error::InvalidOption {
                name: format!("estimators.{label}.label"),
                reason: format!("is used twice in {}; give each estimator its own label", path.display()),
            });
        }
        out.push(Labelled { label, estimator });
    }
    Ok(out)
}
