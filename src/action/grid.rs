//! Tensor grids of one to three dimensions on which the exact densities live.
//!
//! A grid covers the box ∏_a [lo_a, hi_a] with `cells_a` equal cells per axis; axis a is state a
//! of s = [x; z] (noisy then clean states). Densities are stored as *cell masses* (probability
//! of each cell, summing to 1), indexed `i0 + n0 · i1 + n0 · n1 · i2` (axis 0 fastest).

use serde::{Deserialize, Deserializer, Serialize, Serializer};

use crate::{Error, Result};

/// The most axes a grid has ([`GridSpec::validate`]), and so the most states of a model that the
/// exact grid methods take (docs/effective-action.md, "Three states").
pub const MAX_AXES: usize = 3;

/// The box and resolution of a grid: one entry per axis (one to three axes).
///
/// In options files and on the command line a grid is written `lo=L,hi=H,cells=N` (two axes:
/// `lo=L1;L2,hi=H1;H2,cells=N1;N2`, three likewise, [`GridSpec::parse`]) or as a table
/// `{ lo = [L1, L2], hi = [H1, H2], cells = [N1, N2] }` (one axis: plain numbers); it is
/// written back in the first form.
#[derive(Debug, Clone, PartialEq)]
pub struct GridSpec {
    /// Lower end of each axis.
    pub lo: Vec<f64>,
    /// Upper end of each axis.
    pub hi: Vec<f64>,
    /// Number of cells of each axis (at least 3).
    pub cells: Vec<usize>,
}

/// One number per axis, or a list of them (the table form of a [`GridSpec`]).
#[derive(Deserialize)]
#[serde(untagged)]
enum PerAxis<T> {
    One(T),
    Each(Vec<T>),
}

impl<T> PerAxis<T> {
    fn into_vec(self) -> Vec<T> {
        match self {
            PerAxis::One(v) => vec![v],
            PerAxis::Each(v) => v,
        }
    }
}

/// The forms a grid is written in.
#[derive(Deserialize)]
#[serde(untagged)]
enum GridForm {
    Text(String),
    Table { lo: PerAxis<f64>, hi: PerAxis<f64>, cells: PerAxis<usize> },
}

impl<'de> Deserialize<'de> for GridSpec {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> std::result::Result<Self, D::Error> {
        let form = GridForm::deserialize(deserializer).map_err(|_| {
            serde::de::Error::custom("expected `lo=L,hi=H,cells=N` or a table { lo = …, hi = …, cells = … }")
        })?;
        let spec = match form {
            GridForm::Text(text) => GridSpec::parse(&text),
            GridForm::Table { lo, hi, cells } => {
                let g = GridSpec { lo: lo.into_vec(), hi: hi.into_vec(), cells: cells.into_vec() };
                g.validate().map(|()| g)
            }
        };
        spec.map_err(|e| match e {
            Error::InvalidOption { reason, .. } => serde::de::Error::custom(reason),
            other => serde::de::Error::custom(other),
        })
    }
}

impl Serialize for GridSpec {
    fn serialize<S: Serializer>(&self, serializer: S) -> std::result::Result<S::Ok, S::Error> {
        serializer.serialize_str(&self.to_string())
    }
}

impl std::fmt::Display for GridSpec {
    /// The command-line form `lo=L1;L2,hi=H1;H2,cells=N1;N2`, which [`GridSpec::parse`] reads
    /// back.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let join = |v: Vec<String>| v.join(";");
        write!(
            f,
            "lo={},hi={},cells={}",
            join(self.lo.iter().map(|x| x.to_string()).collect()),
            join(self.hi.iter().map(|x| x.to_string()).collect()),
            join(self.cells.iter().map(|x| x.to_string()).collect())
        )
    }
}

fn bad(reason: impl Into<String>) -> Error {
    Error::InvalidOption { name: "grid".into(), reason: reason.into() }
}

impl GridSpec {
    /// A one-dimensional grid [lo, hi] with `cells` cells.
    pub fn new_1d(lo: f64, hi: f64, cells: usize) -> GridSpec {
        GridSpec { lo: vec![lo], hi: vec![hi], cells: vec![cells] }
    }

    /// A two-dimensional grid [lo₀, hi₀] × [lo₁, hi₁] with `cells[0] × cells[1]` cells.
    pub fn new_2d(lo: [f64; 2], hi: [f64; 2], cells: [usize; 2]) -> GridSpec {
        GridSpec { lo: lo.to_vec(), hi: hi.to_vec(), cells: cells.to_vec() }
    }

    /// Number of axes.
    pub fn dim(&self) -> usize {
        self.cells.len()
    }

    /// Parses the CLI syntax `lo=L,hi=H,cells=N` (one axis) or `lo=L1;L2,hi=H1;H2,cells=N1;N2`
    /// (two axes; three likewise). Errors: [`Error::InvalidOption`] (name `grid`) naming the
    /// problem.
    pub fn parse(spec: &str) -> Result<GridSpec> {
        let (mut lo, mut hi, mut cells) = (None, None, None);
        for part in spec.split(',') {
            let (k, v) = part
                .split_once('=')
                .ok_or_else(|| bad(format!("`{part}`: expected KEY=VALUE (keys lo, hi, cells)")))?;
            let nums = |what: &str| -> Result<Vec<f64>> {
                v.split(';')
                    .map(|s| {
                        s.trim()
                            .parse::<f64>()
                            .map_err(|_| bad(format!("cannot parse `{s}` as a number for {what}")))
                    })
                    .collect()
            };
            match k.trim() {
                "lo" => lo = Some(nums("lo")?),
                "hi" => hi = Some(nums("hi")?),
                "cells" => {
                    let c = v
                        .split(';')
                        .map(|s| {
                            s.trim()
                                .parse::<usize>()
                                .map_err(|_| bad(format!("cannot parse `{s}` as a cell count")))
                        })
                        .collect::<Result<Vec<usize>>>()?;
                    cells = Some(c);
                }
                other => return Err(bad(format!("unknown key `{other}` (keys: lo, hi, cells)"))),
            }
        }
        let g = GridSpec {
            lo: lo.ok_or_else(|| bad("missing `lo`"))?,
            hi: hi.ok_or_else(|| bad("missing `hi`"))?,
            cells: cells.ok_or_else(|| bad("missing `cells`"))?,
        };
        g.validate()?;
        Ok(g)
    }

    /// Checks one to three axes, the same number of entries in `lo`, `hi`, `cells`, finite
    /// lo < hi and at least 3 cells per axis.
    pub fn validate(&self) -> Result<()> {
        let d = self.cells.len();
        if !(1..=MAX_AXES).contains(&d) {
            return Err(bad(format!("the grid methods support 1 to {MAX_AXES} axes, got {d}")));
        }
        if self.lo.len() != d || self.hi.len() != d {
            return Err(bad(format!(
                "lo, hi and cells must have the same number of entries (got {}, {}, {d})",
                self.lo.len(),
                self.hi.len()
            )));
        }
        for a in 0..d {
            let (l, h) = (self.lo[a], self.hi[a]);
            if !(l.is_finite() && h.is_finite() && l < h) {
                return Err(bad(format!("axis {a}: need finite lo < hi, got lo = {l}, hi = {h}")));
            }
            if self.cells[a] < 3 {
                return Err(bad(format!("axis {a}: need at least 3 cells, got {}", self.cells[a])));
            }
        }
        Ok(())
    }
}

/// A validated grid with its cell widths and centres.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    spec: GridSpec,
    h: Vec<f64>,
    centers: Vec<Vec<f64>>,
}

impl Grid {
    /// Builds the grid; errors as [`GridSpec::validate`].
    pub fn try_new(spec: GridSpec) -> Result<Grid> {
        spec.validate()?;
        let d = spec.dim();
        let h: Vec<f64> = (0..d).map(|a| (spec.hi[a] - spec.lo[a]) / spec.cells[a] as f64).collect();
        let centers = (0..d)
            .map(|a| (0..spec.cells[a]).map(|i| spec.lo[a] + (i as f64 + 0.5) * h[a]).collect())
            .collect();
        Ok(Grid { spec, h, centers })
    }

    /// The specification.
    pub fn spec(&self) -> &GridSpec {
        &self.spec
    }

    /// Number of axes.
    pub fn dim(&self) -> usize {
        self.spec.dim()
    }

    /// Number of cells in all.
    pub fn len(&self) -> usize {
        self.spec.cells.iter().product()
    }

    /// Never true (a valid grid has at least 3 cells).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Cells per axis.
    pub fn cells(&self) -> &[usize] {
        &self.spec.cells
    }

    /// Cell width of each axis.
    pub fn widths(&self) -> &[f64] {
        &self.h
    }

    /// Cell centres of axis `a`.
    pub fn centers(&self, a: usize) -> &[f64] {
        &self.centers[a]
    }

    /// The coordinates of cell `cell` (index `i0 + n0 · i1 + n0 · n1 · i2`) into `out` (length
    /// [`Grid::dim`]).
    pub fn coords(&self, cell: usize, out: &mut [f64]) {
        let mut rest = cell;
        for ((o, centers), &n) in out.iter_mut().zip(&self.centers).zip(&self.spec.cells) {
            *o = centers[rest % n];
            rest /= n;
        }
    }

    /// The index along axis `a` of cell `cell`.
    pub fn index_on(&self, a: usize, cell: usize) -> usize {
        let below: usize = self.spec.cells[..a].iter().product();
        (cell / below) % self.spec.cells[a]
    }

    /// The values of axis `a`'s coordinate at every cell.
    pub fn coordinate(&self, a: usize) -> Vec<f64> {
        let mut c = vec![0.0; self.dim()];
        (0..self.len())
            .map(|i| {
                self.coords(i, &mut c);
                c[a]
            })
            .collect()
    }

    /// Whether `value` lies in [lo_a, hi_a].
    pub fn covers(&self, a: usize, value: f64) -> bool {
        value >= self.spec.lo[a] && value <= self.spec.hi[a]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_grid_is_written_as_text_and_read_from_text_or_a_table() {
        let g = GridSpec::new_2d([-1.5, -2.0], [1.5, 2.0], [30, 40]);
        assert_eq!(g.to_string(), "lo=-1.5;-2,hi=1.5;2,cells=30;40");
        assert_eq!(GridSpec::parse(&g.to_string()).unwrap(), g);
        let json = serde_json::to_value(&g).unwrap();
        assert_eq!(serde_json::from_value::<GridSpec>(json).unwrap(), g);
        let table = serde_json::json!({"lo": [-1.5, -2.0], "hi": [1.5, 2.0], "cells": [30, 40]});
        assert_eq!(serde_json::from_value::<GridSpec>(table).unwrap(), g);
        let one = serde_json::json!({"lo": -1, "hi": 1, "cells": 10});
        assert_eq!(serde_json::from_value::<GridSpec>(one).unwrap(), GridSpec::new_1d(-1.0, 1.0, 10));
        let bad = serde_json::from_value::<GridSpec>(serde_json::json!("lo=1,hi=0,cells=10")).unwrap_err();
        assert!(bad.to_string().contains("lo < hi"), "{bad}");
    }

    #[test]
    fn parse_one_two_and_three_axes() {
        let g = GridSpec::parse("lo=-2,hi=3,cells=50").unwrap();
        assert_eq!(g, GridSpec::new_1d(-2.0, 3.0, 50));
        let g = GridSpec::parse("lo=-2;-1, hi=2;1, cells=20;10").unwrap();
        assert_eq!(g, GridSpec::new_2d([-2.0, -1.0], [2.0, 1.0], [20, 10]));
        let g = GridSpec::parse("lo=-2;-1;0,hi=2;1;4,cells=20;10;5").unwrap();
        assert_eq!((g.lo, g.hi, g.cells), (vec![-2.0, -1.0, 0.0], vec![2.0, 1.0, 4.0], vec![20, 10, 5]));
        for badspec in ["lo=1,hi=0,cells=10", "lo=0,hi=1", "lo=0,hi=1,cells=2", "lo=0;1,hi=1,cells=4", "x=1"]
        {
            assert!(matches!(GridSpec::parse(badspec), Err(Error::InvalidOption { .. })), "{badspec}");
        }
    }

    #[test]
    fn centres_and_coordinates() {
        let g = Grid::try_new(GridSpec::new_2d([0.0, -1.5], [1.0, 1.5], [4, 3])).unwrap();
        // h = (0.25, 1): centres 0.125 + 0.25 i and −1, 0, 1; cell 5 = (i0, i1) = (1, 1).
        assert_eq!(g.len(), 12);
        let mut c = [0.0; 2];
        g.coords(5, &mut c);
        assert_eq!(c, [0.375, 0.0]);
        assert_eq!(g.coordinate(1)[3], -1.0);
        assert_eq!((g.index_on(0, 5), g.index_on(1, 5)), (1, 1));
        // Three axes: h = (0.5, 1, 2), cell 1 + 4·1 + 4·3·2 = 29 = (1, 1, 2).
        let g = Grid::try_new(GridSpec::parse("lo=0;0;-3,hi=2;3;3,cells=4;3;3").unwrap()).unwrap();
        assert_eq!(g.len(), 36);
        let mut c = [0.0; 3];
        g.coords(29, &mut c);
        assert_eq!(c, [0.75, 1.5, 2.0]);
        assert_eq!((0..3).map(|a| g.index_on(a, 29)).collect::<Vec<_>>(), [1, 1, 2]);
        let four = GridSpec::parse("lo=0;0;0;0,hi=1;1;1;1,cells=3;3;3;3").unwrap_err();
        assert!(four.to_string().contains("1 to 3 axes"), "{four}");
    }
}
