//! Continuous-time measurement records (`003_d2fc48a470e528fc.txt` Sec. I.4, (I.26)): the
//! observation dY = B x(t) dt + R^{1/2} dW of the measured states x through a record of
//! intensity R, seen on a regular grid of cells of width Δ.
//!
//! A record is stored as the signal averaged over each cell,
//! y_k = (Y(t_k + Δ/2) − Y(t_k − Δ/2))/Δ, at the cell midpoints t_k. Given the path, y_k is
//! Gaussian with mean the cell average of B x and variance R/Δ, so the record is a set of
//! discrete Gaussian measurements of B x(t_k) with standard deviation √(R/Δ) (the cell average
//! differs from the midpoint value by a term of variance O(GGᵀΔ), a fraction O(Δ²) of R/Δ; see
//! docs/effective-action.md, "Continuous-time records"). Every
//! estimator of discrete Gaussian data therefore takes a record as it is, and converges under
//! refinement of Δ to its continuous-time form: the KSP smoother to the Kushner–Stratonovich
//! and Pardoux equations (003 (0.3)–(0.7)), the mean-optimal estimator to (I.27)–(I.38) with the
//! control field h(t) piecewise constant on the cells.
//!
//! File format: a measurement CSV (`t,<outputs>`, see [`super::Dataset`]) whose first line is
//! `# continuous: R=<intensity>`; the times must be the cell midpoints of a regular grid (steps
//! equal within 10⁻⁶ relative), an empty cell or `NaN` is a gap in the record.

use std::fs::File;
use std::io::{BufRead, BufReader, Read, Write};
use std::path::Path;

use super::{data_err, in_memory, Dataset};
use crate::model::observation::{Noise, Param};
use crate::{Error, Result};

/// The first-line marker of a continuous record file.
pub const MARKER: &str = "# continuous:";

/// Relative tolerance on the steps of a record's time grid.
const GRID_TOL: f64 = 1e-6;

/// A continuous-time record of intensity R seen on a regular grid of cells: the cell averages
/// of the signal, at the cell midpoints.
#[derive(Debug, Clone, PartialEq)]
pub struct ContinuousRecord {
    /// Noise intensity R > 0 of the record (per unit time: dY = B x dt + R^{1/2} dW).
    pub intensity: f64,
    /// The cell averages at the cell midpoints (a regular grid of at least two times); NaN
    /// marks a gap.
    pub data: Dataset,
}

impl ContinuousRecord {
    /// A record of intensity `intensity` with the cell averages `data`. Errors:
    /// [`Error::Data`] (naming `<memory>`) for a non-positive or non-finite intensity, fewer
    /// than two times, or an irregular grid.
    pub fn try_new(intensity: f64, data: Dataset) -> Result<ContinuousRecord> {
        let path = in_memory();
        check_intensity(intensity, &path, 1)?;
        let lines: Vec<usize> = (0..data.len()).map(|i| i + 2).collect();
        check_grid(&data.times, &path, &lines)?;
        Ok(ContinuousRecord { intensity, data })
    }

    /// The cell width Δ (the grid's step).
    pub fn cell(&self) -> f64 {
        let n = self.data.len();
        (self.data.times[n - 1] - self.data.times[0]) / (n - 1) as f64
    }

    /// The variance R/Δ of one cell average given the path.
    pub fn variance(&self) -> f64 {
        self.intensity / self.cell()
    }

    /// The discrete measurement law of the cell averages: Gaussian with σ = √(R/Δ).
    pub fn noise(&self) -> Noise {
        Noise::Gaussian { sigma: Param::Fixed(self.variance().sqrt()) }
    }

    /// Whether the file `path` starts with the marker [`MARKER`]. Errors: I/O.
    pub fn is_record_file(path: impl AsRef<Path>) -> Result<bool> {
        let path = path.as_ref();
        let io = |source| Error::Io { path: path.to_path_buf(), source };
        let mut first = String::new();
        BufReader::new(File::open(path).map_err(io)?).read_line(&mut first).map_err(io)?;
        Ok(first.trim_start().starts_with(MARKER))
    }

    /// Reads a record file for a model whose outputs are `outputs` (as
    /// [`Dataset::read_csv_for`]).
    pub fn read_csv_for(path: impl AsRef<Path>, outputs: &[String]) -> Result<ContinuousRecord> {
        let path = path.as_ref();
        let file = File::open(path).map_err(|source| Error::Io { path: path.to_path_buf(), source })?;
        Self::from_reader(file, path, Some(outputs))
    }

    /// Parses a record from any reader; `path` names the source in errors, `outputs` as in
    /// [`Dataset::from_reader`]. Errors ([`Error::Data`], naming the line and, where it
    /// concerns one cell, the column): a missing or malformed first line, a missing, repeated,
    /// unknown or non-positive key, fewer than two rows, an irregular grid, and every error of
    /// the measurement CSV reader.
    pub fn from_reader<R: Read>(
        reader: R,
        path: &Path,
        outputs: Option<&[String]>,
    ) -> Result<ContinuousRecord> {
        let mut reader = BufReader::new(reader);
        let mut first = String::new();
        reader
            .read_line(&mut first)
            .map_err(|e| data_err(path, 1, None, format!("cannot read the first line: {e}")))?;
        let intensity = parse_marker(&first, path)?;
        let (data, lines) = Dataset::from_reader_at(reader, path, outputs, 1)?;
        check_grid(&data.times, path, &lines)?;
        Ok(ContinuousRecord { intensity, data })
    }

    /// Writes the record: the marker line, then the measurement CSV.
    pub fn write_csv(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let io = |source| Error::Io { path: path.to_path_buf(), source };
        let mut out = std::io::BufWriter::new(File::create(path).map_err(io)?);
        writeln!(out, "{MARKER} R={}", self.intensity).map_err(io)?;
        super::write_rows(&mut out, path, &self.data)?;
        out.flush().map_err(io)
    }
}

/// The midpoints of the cells of width `cell` that fit in [t0, t_end] (the first starting at
/// t0), within 10⁻⁹ relative.
pub fn cell_midpoints(t0: f64, t_end: f64, cell: f64) -> Vec<f64> {
    if !(t0.is_finite() && t_end.is_finite() && cell.is_finite() && cell > 0.0 && t_end > t0) {
        return Vec::new();
    }
    let n = ((t_end - t0) / cell * (1.0 + 1e-9)).floor() as usize;
    (0..n).map(|k| t0 + (k as f64 + 0.5) * cell).collect()
}

fn check_intensity(r: f64, path: &Path, line: usize) -> Result<()> {
    if r.is_finite() && r > 0.0 {
        Ok(())
    } else {
        Err(data_err(path, line, None, format!("the intensity R must be positive and finite, got {r}")))
    }
}

/// The intensity R of the marker line `# continuous: R=<value>`.
fn parse_marker(line: &str, path: &Path) -> Result<f64> {
    let line = line.trim();
    let Some(rest) = line.strip_prefix(MARKER) else {
        return Err(data_err(
            path,
            1,
            None,
            format!("a continuous record starts with `{MARKER} R=<intensity>`, found `{line}`"),
        ));
    };
    let mut intensity = None;
    for part in rest.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let Some((key, value)) = part.split_once('=') else {
            return Err(data_err(path, 1, None, format!("expected KEY=VALUE, found `{part}`")));
        };
        match key.trim() {
            "R" if intensity.is_some() => {
                return Err(data_err(path, 1, None, "`R` is given twice"));
            }
            "R" => {
                let r: f64 = value.trim().parse().map_err(|_| {
                    data_err(path, 1, None, format!("cannot parse `{}` as the intensity R", value.trim()))
                })?;
                check_intensity(r, path, 1)?;
                intensity = Some(r);
            }
            other => return Err(data_err(path, 1, None, format!("unknown key `{other}` (known: R)"))),
        }
    }
    intensity.ok_or_else(|| data_err(path, 1, None, "the intensity `R=<value>` is missing"))
}

/// Checks that `times` (on the file lines `lines`) are a regular grid of at least two times.
fn check_grid(times: &[f64], path: &Path, lines: &[usize]) -> Result<()> {
    let n = times.len();
    if n < 2 {
        let line = lines.last().map_or(2, |&l| l);
        return Err(data_err(
            path,
            line,
            None,
            format!(
                "a continuous record needs at least two times (its grid's step is the cell width), found {n}"
            ),
        ));
    }
    let cell = times[1] - times[0];
    for (i, w) in times.windows(2).enumerate() {
        let step = w[1] - w[0];
        if (step - cell).abs() > GRID_TOL * cell {
            return Err(data_err(
                path,
                lines[i + 1],
                Some("1 (t)".into()),
                format!(
                    "a continuous record's times must be a regular grid: the step {step} from {} differs \
                     from the first step {cell}",
                    w[0]
                ),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<ContinuousRecord> {
        ContinuousRecord::from_reader(text.as_bytes(), Path::new("record.csv"), None)
    }

    fn expect_error(text: &str, line: usize, column: Option<&str>, needle: &str) {
        match parse(text) {
            Err(Error::Data { path, line: l, column: c, reason }) => {
                assert_eq!(path, Path::new("record.csv"));
                assert_eq!(l, line, "line; reason: {reason}");
                assert_eq!(c.as_deref(), column, "column; reason: {reason}");
                assert!(reason.contains(needle), "`{reason}` should mention `{needle}`");
            }
            other => panic!("expected a data error for {text:?}, got {other:?}"),
        }
    }

    #[test]
    fn reads_a_record_with_a_gap_and_converts_it() {
        let r = parse("# continuous: R=0.16\nt,y\n0.05,1\n0.15,\n0.25,-0.5\n").unwrap();
        assert_eq!(r.intensity, 0.16);
        assert_eq!(r.data.times, vec![0.05, 0.15, 0.25]);
        assert!(r.data.values[1][0].is_nan());
        assert!((r.cell() - 0.1).abs() < 1e-15);
        // R/Δ = 1.6.
        assert!((r.variance() - 1.6).abs() < 1e-12);
        match r.noise() {
            Noise::Gaussian { sigma: Param::Fixed(s) } => assert!((s * s - 1.6).abs() < 1e-12),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn round_trip_is_exact() {
        let data = Dataset::try_new(
            vec!["y".into()],
            vec![0.005, 0.015, 0.025],
            vec![vec![1.0 / 3.0], vec![f64::NAN], vec![-2.0]],
        )
        .unwrap();
        let r = ContinuousRecord::try_new(0.09, data).unwrap();
        let dir = std::env::temp_dir().join(format!("onsager-record-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("record.csv");
        r.write_csv(&file).unwrap();
        assert!(ContinuousRecord::is_record_file(&file).unwrap());
        let back = ContinuousRecord::read_csv_for(&file, &["y".to_string()]).unwrap();
        assert_eq!(back.intensity, r.intensity);
        assert_eq!(back.data.times, r.data.times);
        assert!(back.data.values[1][0].is_nan());
        assert_eq!(back.data.values[0][0], 1.0 / 3.0);
        // A plain measurement file is not a record.
        r.data.write_csv(&file).unwrap();
        assert!(!ContinuousRecord::is_record_file(&file).unwrap());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bad_records_name_file_line_and_column() {
        // The marker line.
        expect_error("t,y\n0,1\n1,2\n", 1, None, "starts with `# continuous:");
        expect_error("# continuous:\nt,y\n0,1\n1,2\n", 1, None, "missing");
        expect_error("# continuous: R=0\nt,y\n0,1\n1,2\n", 1, None, "positive");
        expect_error("# continuous: R=-0.1\nt,y\n0,1\n1,2\n", 1, None, "positive");
        expect_error("# continuous: R=abc\nt,y\n0,1\n1,2\n", 1, None, "cannot parse `abc`");
        expect_error("# continuous: R=1,R=2\nt,y\n0,1\n1,2\n", 1, None, "twice");
        expect_error("# continuous: R=1,dt=2\nt,y\n0,1\n1,2\n", 1, None, "unknown key `dt`");
        expect_error("# continuous: R\nt,y\n0,1\n1,2\n", 1, None, "KEY=VALUE");
        // The grid: irregular, non-increasing, too short.
        expect_error("# continuous: R=1\nt,y\n0,1\n0.1,2\n0.3,2\n", 5, Some("1 (t)"), "regular grid");
        expect_error("# continuous: R=1\nt,y\n0,1\n0.1,2\n0.1,2\n", 5, Some("t"), "strictly increasing");
        expect_error("# continuous: R=1\nt,y\n0,1\n", 3, None, "at least two times");
        // Cells: the lines count the marker line.
        expect_error("# continuous: R=1\nt,y\n0,1\n0.1,abc\n", 4, Some("2 (y)"), "cannot parse `abc`");
        expect_error("# continuous: R=1\nt,y\n0,1\nx,2\n", 4, Some("1 (t)"), "cannot parse `x`");
        expect_error("# continuous: R=1\ntime,y\n0,1\n", 2, Some("1"), "first column must be `t`");
    }

    #[test]
    fn try_new_checks_the_intensity_and_the_grid() {
        let data =
            |t: Vec<f64>| Dataset::try_new(vec!["y".into()], t.clone(), vec![vec![0.0]; t.len()]).unwrap();
        assert!(ContinuousRecord::try_new(0.0, data(vec![0.0, 1.0])).is_err());
        assert!(ContinuousRecord::try_new(f64::NAN, data(vec![0.0, 1.0])).is_err());
        assert!(ContinuousRecord::try_new(1.0, data(vec![0.0])).is_err());
        assert!(ContinuousRecord::try_new(1.0, data(vec![0.0, 1.0, 3.0])).is_err());
        assert!(ContinuousRecord::try_new(1.0, data(vec![0.0, 1.0, 2.0])).is_ok());
    }

    #[test]
    fn cell_midpoints_fill_the_span() {
        let m = cell_midpoints(0.0, 1.0, 0.25);
        assert_eq!(m, vec![0.125, 0.375, 0.625, 0.875]);
        // A partial last cell is left out; rounding does not drop a full one.
        assert_eq!(cell_midpoints(0.0, 1.1, 0.25).len(), 4);
        assert_eq!(cell_midpoints(0.0, 0.3, 0.1).len(), 3);
        assert!(cell_midpoints(0.0, 1.0, 0.0).is_empty());
    }
}
