//! The built-in experiments: TOML specs shipped with the crate (`experiments/*.toml`).

use super::spec::Experiment;
use crate::{Error, Result};

/// (name, TOML text) of every built-in experiment.
pub const BUILTIN: &[(&str, &str)] = &[
    ("tanh-limits", include_str!("../../experiments/tanh-limits.toml")),
    ("vdp-robust", include_str!("../../experiments/vdp-robust.toml")),
    ("duffing-gaussian", include_str!("../../experiments/duffing-gaussian.toml")),
    ("duffing-outliers", include_str!("../../experiments/duffing-outliers.toml")),
    ("holmes-rand-quantized", include_str!("../../experiments/holmes-rand-quantized.toml")),
    ("double-well-jumps", include_str!("../../experiments/double-well-jumps.toml")),
    ("double-well-branch", include_str!("../../experiments/double-well-branch.toml")),
    ("lorenz63-smoothing", include_str!("../../experiments/lorenz63-smoothing.toml")),
    ("lorenz96-smoothing", include_str!("../../experiments/lorenz96-smoothing.toml")),
    ("closures-2d", include_str!("../../experiments/closures-2d.toml")),
    ("double-well-continuous", include_str!("../../experiments/double-well-continuous.toml")),
];

/// The TOML text of the built-in experiment `name`; [`Error::UnknownName`] (kind
/// `experiment`) otherwise.
pub fn builtin_text(name: &str) -> Result<&'static str> {
    BUILTIN.iter().find(|(n, _)| *n == name).map(|(_, t)| *t).ok_or_else(|| Error::UnknownName {
        kind: "experiment".into(),
        name: name.into(),
        known: BUILTIN.iter().map(|(n, _)| n.to_string()).collect(),
    })
}

/// The built-in experiment `name`, parsed.
pub fn builtin(name: &str) -> Result<Experiment> {
    Experiment::from_toml(builtin_text(name)?)
}

/// A built-in experiment by name, or a spec file: `name_or_path` ending in `.toml` or naming
/// an existing file is read as a file, anything else is a built-in name. Errors: an unknown
/// name ([`Error::UnknownName`]), I/O, an invalid spec (naming the file and the key).
pub fn load(name_or_path: &str) -> Result<Experiment> {
    let path = std::path::Path::new(name_or_path);
    if name_or_path.ends_with(".toml") || path.is_file() {
        Experiment::from_path(path).map_err(|e| match e {
            Error::InvalidOption { name, reason } => {
                Error::InvalidOption { name, reason: format!("in {name_or_path}: {reason}") }
            }
            other => other,
        })
    } else {
        builtin(name_or_path)
    }
}
