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
    ("lorenz63-smoothing", include_str!("../../experiments/lorenz63-smoothing.toml")),
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
