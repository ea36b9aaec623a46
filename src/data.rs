//! Measurement datasets and state paths, with CSV reading and writing.
//!
//! Formats (DESIGN.md, "Data formats"):
//! - measurements: header `t,<output names...>`, one row per measurement time, strictly
//!   increasing finite `t`, an empty cell or `NaN` for a missing value;
//! - paths: header `t,<state names...>,sd_<state>...`, the sd cells empty where a path has no
//!   standard deviations (so that the layout does not depend on the method); reading also
//!   accepts a file without `sd_` columns.
//!
//! Every malformed input is an [`Error::Data`] naming the file, the line (the header is line 1)
//! and, where it concerns one cell, the column.

use std::fs::File;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use crate::{Error, Result};

pub mod continuous;

/// A table of measurements: one row per measurement time, NaN for a missing value.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    /// Output names (the CSV columns after `t`).
    pub names: Vec<String>,
    /// Strictly increasing, finite measurement times.
    pub times: Vec<f64>,
    /// One row per time, one value per output; NaN marks a missing value.
    pub values: Vec<Vec<f64>>,
}

/// A state path: one row per time, noisy states then clean states, with optional standard
/// deviations.
#[derive(Debug, Clone, PartialEq)]
pub struct StatePath {
    /// State names.
    pub names: Vec<String>,
    /// Times.
    pub times: Vec<f64>,
    /// One row per time.
    pub values: Vec<Vec<f64>>,
    /// Optional standard deviations, same shape as `values`.
    pub sd: Option<Vec<Vec<f64>>>,
}

fn in_memory() -> PathBuf {
    PathBuf::from("<memory>")
}

fn data_err(path: &Path, line: usize, column: Option<String>, reason: impl Into<String>) -> Error {
    Error::Data { path: path.to_path_buf(), line, column, reason: reason.into() }
}

/// Checks that times are finite and strictly increasing; `line_of(i)` gives the line of row i.
fn check_times(times: &[f64], path: &Path, line_of: impl Fn(usize) -> usize) -> Result<()> {
    for (i, &t) in times.iter().enumerate() {
        if !t.is_finite() {
            return Err(data_err(path, line_of(i), Some("t".into()), format!("time {t} is not finite")));
        }
        if i > 0 && t <= times[i - 1] {
            return Err(data_err(
                path,
                line_of(i),
                Some("t".into()),
                format!("times must be strictly increasing: {t} follows {}", times[i - 1]),
            ));
        }
    }
    Ok(())
}

impl Dataset {
    /// Builds a dataset, checking shapes, that times are finite and strictly increasing, and
    /// that values are finite or NaN (missing).
    pub fn try_new(names: Vec<String>, times: Vec<f64>, values: Vec<Vec<f64>>) -> Result<Dataset> {
        let path = in_memory();
        if values.len() != times.len() {
            return Err(Error::DimensionMismatch {
                what: "dataset rows".into(),
                expected: times.len(),
                got: values.len(),
            });
        }
        check_times(&times, &path, |i| i + 2)?;
        for (i, row) in values.iter().enumerate() {
            if row.len() != names.len() {
                return Err(data_err(
                    &path,
                    i + 2,
                    None,
                    format!("expected {} values, found {}", names.len(), row.len()),
                ));
            }
            if let Some(j) = row.iter().position(|v| v.is_infinite()) {
                return Err(data_err(&path, i + 2, Some(names[j].clone()), "infinite value"));
            }
        }
        Ok(Dataset { names, times, values })
    }

    /// Number of measurement times.
    pub fn len(&self) -> usize {
        self.times.len()
    }

    /// Whether there are no measurement times.
    pub fn is_empty(&self) -> bool {
        self.times.is_empty()
    }

    /// Reads a measurement CSV file with any output names.
    pub fn read_csv(path: impl AsRef<Path>) -> Result<Dataset> {
        let path = path.as_ref();
        let file = File::open(path).map_err(|source| Error::Io { path: path.to_path_buf(), source })?;
        Self::from_reader(file, path, None)
    }

    /// Reads a measurement CSV file for a model whose outputs are `outputs`: every column after
    /// `t` must name one of them (in any order); outputs without a column are missing
    /// throughout. The result's columns are in the order of `outputs`.
    pub fn read_csv_for(path: impl AsRef<Path>, outputs: &[String]) -> Result<Dataset> {
        let path = path.as_ref();
        let file = File::open(path).map_err(|source| Error::Io { path: path.to_path_buf(), source })?;
        Self::from_reader(file, path, Some(outputs))
    }

    /// Parses measurement CSV from any reader; `path` names the source in errors and
    /// `outputs`, if given, are the names the columns must come from.
    pub fn from_reader<R: Read>(reader: R, path: &Path, outputs: Option<&[String]>) -> Result<Dataset> {
        Self::from_reader_at(reader, path, outputs, 0).map(|(data, _)| data)
    }

    /// As [`Dataset::from_reader`] for text that starts after `offset` lines of its file (errors
    /// name the file's lines); also returns the file line of every row.
    pub(crate) fn from_reader_at<R: Read>(
        reader: R,
        path: &Path,
        outputs: Option<&[String]>,
        offset: usize,
    ) -> Result<(Dataset, Vec<usize>)> {
        let table = read_table(reader, path, offset)?;
        let header = &table.header;
        let names: Vec<String> = header[1..].to_vec();
        // Map file columns to result columns.
        let (out_names, map): (Vec<String>, Vec<usize>) = match outputs {
            None => (names.clone(), (0..names.len()).collect()),
            Some(outputs) => {
                let mut map = Vec::with_capacity(names.len());
                for (j, name) in names.iter().enumerate() {
                    match outputs.iter().position(|o| o == name) {
                        Some(k) => map.push(k),
                        None => {
                            return Err(data_err(
                                path,
                                offset + 1,
                                Some(format!("{} ({name})", j + 2)),
                                format!(
                                    "unknown output `{name}` (the model's outputs: {})",
                                    outputs.join(", ")
                                ),
                            ))
                        }
                    }
                }
                (outputs.to_vec(), map)
            }
        };
        let mut times = Vec::with_capacity(table.rows.len());
        let mut values = Vec::with_capacity(table.rows.len());
        for (line, row) in &table.rows {
            let t = parse_cell(&row[0], path, *line, 1, "t", false)?;
            let mut v = vec![f64::NAN; out_names.len()];
            for (j, cell) in row[1..].iter().enumerate() {
                v[map[j]] = parse_cell(cell, path, *line, j + 2, &names[j], true)?;
            }
            times.push(t);
            values.push(v);
        }
        let lines: Vec<usize> = table.rows.iter().map(|(l, _)| *l).collect();
        check_times(&times, path, |i| lines[i])?;
        Ok((Dataset { names: out_names, times, values }, lines))
    }

    /// Writes the dataset as CSV; missing values are written as empty cells.
    pub fn write_csv(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let io = |source| Error::Io { path: path.to_path_buf(), source };
        let mut out = std::io::BufWriter::new(File::create(path).map_err(io)?);
        write_rows(&mut out, path, self)?;
        out.flush().map_err(io)
    }
}

impl StatePath {
    /// The path at those of `times` that lie inside its span (the others are left out), every
    /// state and sd interpolated linearly ([`crate::metrics::interpolate`]).
    pub fn at_times(&self, times: &[f64]) -> StatePath {
        let columns = |rows: &[Vec<f64>]| -> Vec<Vec<f64>> {
            (0..self.names.len()).map(|k| rows.iter().map(|r| r[k]).collect()).collect()
        };
        let at = |cols: &[Vec<f64>], t: f64| -> Option<Vec<f64>> {
            cols.iter().map(|c| crate::metrics::interpolate(&self.times, c, t)).collect()
        };
        let values = columns(&self.values);
        let sds = self.sd.as_deref().map(columns);
        let mut out = StatePath { names: self.names.clone(), times: vec![], values: vec![], sd: None };
        let mut out_sd = Vec::new();
        for &t in times {
            let Some(v) = at(&values, t) else { continue };
            out.times.push(t);
            out.values.push(v);
            if let Some(s) = &sds {
                out_sd.push(at(s, t).expect("the sd has the values' times"));
            }
        }
        out.sd = sds.map(|_| out_sd);
        out
    }

    /// Number of times.
    pub fn len(&self) -> usize {
        self.times.len()
    }

    /// Whether the path has no times.
    pub fn is_empty(&self) -> bool {
        self.times.is_empty()
    }

    /// The column of state `name`, if present.
    pub fn column(&self, name: &str) -> Option<Vec<f64>> {
        let j = self.names.iter().position(|n| n == name)?;
        Some(self.values.iter().map(|r| r[j]).collect())
    }

    /// Writes `t,<names>,sd_<names>`: the sd cells are empty where the path has no sd (and
    /// where an sd is NaN).
    pub fn write_csv(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let mut header = vec!["t".to_string()];
        header.extend(self.names.iter().cloned());
        header.extend(self.names.iter().map(|n| format!("sd_{n}")));
        let rows = (0..self.times.len()).map(|i| {
            let mut r = vec![self.times[i]];
            r.extend(&self.values[i]);
            match &self.sd {
                Some(sd) => r.extend(&sd[i]),
                None => r.extend(self.names.iter().map(|_| f64::NAN)),
            }
            r
        });
        write_table(path, &header, rows)
    }

    /// Reads a path CSV (`t,<names>[,sd_<names>]`); the `sd_` columns, if any, must follow
    /// the state columns and match them one to one. A path whose sd cells are all empty has
    /// no sd (`sd` is `None`), as written by [`StatePath::write_csv`].
    pub fn read_csv(path: impl AsRef<Path>) -> Result<StatePath> {
        let path = path.as_ref();
        let file = File::open(path).map_err(|source| Error::Io { path: path.to_path_buf(), source })?;
        Self::from_reader(file, path)
    }

    /// Parses path CSV from any reader; `path` names the source in errors.
    pub fn from_reader<R: Read>(reader: R, path: &Path) -> Result<StatePath> {
        let table = read_table(reader, path, 0)?;
        let cols = &table.header[1..];
        let n_sd = cols.iter().filter(|c| c.starts_with("sd_")).count();
        let n = cols.len() - n_sd;
        let names = cols[..n].to_vec();
        if n_sd > 0 {
            let expected: Vec<String> = names.iter().map(|s| format!("sd_{s}")).collect();
            if n_sd != n || cols[n..] != expected[..] {
                return Err(data_err(
                    path,
                    1,
                    None,
                    format!("sd_ columns must follow the states one to one: expected {}", expected.join(",")),
                ));
            }
        }
        let mut times = Vec::new();
        let mut values = Vec::new();
        let mut sd = Vec::new();
        for (line, row) in &table.rows {
            times.push(parse_cell(&row[0], path, *line, 1, "t", false)?);
            let mut r = Vec::with_capacity(cols.len());
            for (j, cell) in row[1..].iter().enumerate() {
                r.push(parse_cell(cell, path, *line, j + 2, &cols[j], true)?);
            }
            sd.push(r.split_off(n));
            values.push(r);
        }
        let lines: Vec<usize> = table.rows.iter().map(|(l, _)| *l).collect();
        check_times(&times, path, |i| lines[i])?;
        let has_sd = sd.iter().flatten().any(|v| !v.is_nan());
        Ok(StatePath { names, times, values, sd: has_sd.then_some(sd) })
    }
}

/// A sorted time grid holding every measurement time of a dataset and extra times (an output
/// grid, an initial time, …), with the measurement found at each time.
#[derive(Debug, Clone, PartialEq)]
pub struct EventTimes {
    /// The merged, strictly increasing times.
    pub times: Vec<f64>,
    /// For each time, the index of the measurement taken there, if any.
    pub measurement: Vec<Option<usize>>,
    /// For each measurement, the index of its time in `times`.
    pub index_of_measurement: Vec<usize>,
}

impl EventTimes {
    /// Merges strictly increasing `measurement_times` with `extra` times (any order). Every
    /// measurement time is kept, however close to another; an extra time within
    /// 10⁻⁹·(1 + |t|) of a measurement time or of another kept extra time is dropped, so that no
    /// interval of the grid is shorter than that unless two measurements are.
    pub fn merge(measurement_times: &[f64], extra: &[f64]) -> EventTimes {
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * (1.0 + a.abs().max(b.abs()));
        let mut extra: Vec<f64> = extra.to_vec();
        extra.sort_by(f64::total_cmp);
        let mut kept: Vec<f64> = Vec::with_capacity(extra.len());
        for t in extra {
            let i = measurement_times.partition_point(|&m| m < t);
            let near_measurement = [i.checked_sub(1), Some(i)]
                .into_iter()
                .flatten()
                .filter_map(|j| measurement_times.get(j))
                .any(|&m| close(m, t));
            if !near_measurement && kept.last().is_none_or(|&last| !close(last, t)) {
                kept.push(t);
            }
        }
        let n = measurement_times.len() + kept.len();
        let (mut times, mut measurement) = (Vec::with_capacity(n), Vec::with_capacity(n));
        let mut index_of_measurement = Vec::with_capacity(measurement_times.len());
        let (mut i, mut j) = (0, 0);
        while i < measurement_times.len() || j < kept.len() {
            if j == kept.len() || (i < measurement_times.len() && measurement_times[i] < kept[j]) {
                index_of_measurement.push(times.len());
                times.push(measurement_times[i]);
                measurement.push(Some(i));
                i += 1;
            } else {
                times.push(kept[j]);
                measurement.push(None);
                j += 1;
            }
        }
        EventTimes { times, measurement, index_of_measurement }
    }
}

struct Table {
    header: Vec<String>,
    /// (line number, cells)
    rows: Vec<(usize, Vec<String>)>,
}

/// Reads a CSV table whose header is line `offset + 1` of the file `path`.
fn read_table<R: Read>(reader: R, path: &Path, offset: usize) -> Result<Table> {
    let header_line = offset + 1;
    let mut rdr =
        csv::ReaderBuilder::new().has_headers(true).flexible(true).trim(csv::Trim::All).from_reader(reader);
    let header: Vec<String> = rdr
        .headers()
        .map_err(|e| data_err(path, header_line, None, format!("cannot read the header: {e}")))?
        .iter()
        .map(str::to_string)
        .collect();
    if header.is_empty() || header[0] != "t" {
        return Err(data_err(path, header_line, Some("1".into()), "the first column must be `t`"));
    }
    for (j, h) in header.iter().enumerate() {
        if h.is_empty() {
            return Err(data_err(path, header_line, Some((j + 1).to_string()), "empty column name"));
        }
        if header[..j].contains(h) {
            return Err(data_err(
                path,
                header_line,
                Some(format!("{} ({h})", j + 1)),
                format!("duplicate column `{h}`"),
            ));
        }
    }
    let mut rows = Vec::new();
    for rec in rdr.records() {
        let rec = rec.map_err(|e| {
            let line = e.position().map_or(0, |p| p.line() as usize + offset);
            data_err(path, line, None, format!("malformed CSV: {e}"))
        })?;
        let line = rec.position().map_or(0, |p| p.line() as usize + offset);
        if rec.len() == 1 && rec[0].is_empty() {
            continue; // blank line
        }
        if rec.len() != header.len() {
            return Err(data_err(
                path,
                line,
                None,
                format!("expected {} columns (as in the header), found {}", header.len(), rec.len()),
            ));
        }
        rows.push((line, rec.iter().map(str::to_string).collect()));
    }
    Ok(Table { header, rows })
}

/// The largest magnitude of a value in a file: squares (likelihoods, variances) stay finite.
const MAX_MAGNITUDE: f64 = 1e150;

fn parse_cell(cell: &str, path: &Path, line: usize, col: usize, name: &str, missing_ok: bool) -> Result<f64> {
    let column = Some(format!("{col} ({name})"));
    if cell.is_empty() || cell.eq_ignore_ascii_case("nan") {
        return if missing_ok {
            Ok(f64::NAN)
        } else {
            Err(data_err(path, line, column, "a value is required here"))
        };
    }
    let v: f64 = cell
        .parse()
        .map_err(|_| data_err(path, line, column.clone(), format!("cannot parse `{cell}` as a number")))?;
    if !v.is_finite() {
        return Err(data_err(path, line, column, format!("`{cell}` is not finite")));
    }
    if v.abs() > MAX_MAGNITUDE {
        return Err(data_err(
            path,
            line,
            column,
            format!("`{cell}` is too large: its square overflows (|value| at most {MAX_MAGNITUDE:e}); rescale the column"),
        ));
    }
    Ok(v)
}

fn write_table(path: &Path, header: &[String], rows: impl Iterator<Item = Vec<f64>>) -> Result<()> {
    let io = |source| Error::Io { path: path.to_path_buf(), source };
    let mut out = std::io::BufWriter::new(File::create(path).map_err(io)?);
    write_table_to(&mut out, path, header, rows)?;
    out.flush().map_err(io)
}

/// Writes the header and the rows to `out` (`path` names it in errors); NaN as an empty cell.
fn write_table_to<W: Write>(
    out: &mut W,
    path: &Path,
    header: &[String],
    rows: impl Iterator<Item = Vec<f64>>,
) -> Result<()> {
    let io = |source| Error::Io { path: path.to_path_buf(), source };
    writeln!(out, "{}", header.join(",")).map_err(io)?;
    for row in rows {
        let cells: Vec<String> =
            row.iter().map(|v| if v.is_nan() { String::new() } else { format!("{v}") }).collect();
        writeln!(out, "{}", cells.join(",")).map_err(io)?;
    }
    Ok(())
}

/// Writes the measurement CSV of `data` to `out` (`path` names it in errors).
fn write_rows<W: Write>(out: &mut W, path: &Path, data: &Dataset) -> Result<()> {
    let mut header = vec!["t".to_string()];
    header.extend(data.names.iter().cloned());
    let rows = data
        .times
        .iter()
        .zip(&data.values)
        .map(|(&t, row)| std::iter::once(t).chain(row.iter().copied()).collect::<Vec<f64>>());
    write_table_to(out, path, &header, rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Dataset> {
        Dataset::from_reader(text.as_bytes(), Path::new("data.csv"), None)
    }

    fn parse_for(text: &str, outputs: &[&str]) -> Result<Dataset> {
        let outputs: Vec<String> = outputs.iter().map(|s| s.to_string()).collect();
        Dataset::from_reader(text.as_bytes(), Path::new("data.csv"), Some(&outputs))
    }

    fn expect_data_error(r: Result<Dataset>, line: usize, column: Option<&str>, needle: &str) {
        match r {
            Err(Error::Data { path, line: l, column: c, reason }) => {
                assert_eq!(path, Path::new("data.csv"));
                assert_eq!(l, line, "line; reason: {reason}");
                assert_eq!(c.as_deref(), column, "column; reason: {reason}");
                assert!(reason.contains(needle), "`{reason}` should mention `{needle}`");
            }
            other => panic!("expected a data error, got {other:?}"),
        }
    }

    #[test]
    fn reads_missing_values_and_reorders_columns() {
        let d = parse_for("t,y2,y1\n0,1.5,\n0.1,NaN,2\n", &["y1", "y2"]).unwrap();
        assert_eq!(d.names, vec!["y1", "y2"]);
        assert_eq!(d.times, vec![0.0, 0.1]);
        assert!(d.values[0][0].is_nan());
        assert_eq!(d.values[0][1], 1.5);
        assert_eq!(d.values[1][0], 2.0);
        assert!(d.values[1][1].is_nan());
    }

    #[test]
    fn csv_round_trip_is_exact() {
        let d = Dataset::try_new(
            vec!["y1".into(), "y2".into()],
            vec![0.0, 0.1, 0.30000000000000004],
            vec![vec![1.0 / 3.0, f64::NAN], vec![-2.5e-300, 7.0], vec![f64::NAN, f64::NAN]],
        )
        .unwrap();
        let dir = std::env::temp_dir().join(format!("onsager-data-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("round.csv");
        d.write_csv(&file).unwrap();
        let back = Dataset::read_csv(&file).unwrap();
        assert_eq!(back.names, d.names);
        assert_eq!(back.times, d.times);
        for (a, b) in back.values.iter().flatten().zip(d.values.iter().flatten()) {
            assert!(a == b || (a.is_nan() && b.is_nan()), "{a} vs {b}");
        }
        let p = StatePath {
            names: vec!["x".into(), "z".into()],
            times: vec![0.0, 0.5],
            values: vec![vec![1.0, 2.0], vec![3.0, 4.0]],
            sd: Some(vec![vec![0.1, 0.2], vec![0.3, 0.4]]),
        };
        let pf = dir.join("path.csv");
        p.write_csv(&pf).unwrap();
        assert_eq!(StatePath::read_csv(&pf).unwrap(), p);
        // Without sd: the same columns, the sd cells empty; read back without sd.
        let bare = StatePath { sd: None, ..p.clone() };
        bare.write_csv(&pf).unwrap();
        assert_eq!(std::fs::read_to_string(&pf).unwrap(), "t,x,z,sd_x,sd_z\n0,1,2,,\n0.5,3,4,,\n");
        assert_eq!(StatePath::read_csv(&pf).unwrap(), bare);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bad_inputs_name_file_line_and_column() {
        expect_data_error(parse("t,y\n0,1\n0,2\n"), 3, Some("t"), "strictly increasing");
        expect_data_error(parse("t,y\n0,1\n-1,2\n"), 3, Some("t"), "strictly increasing");
        expect_data_error(parse("t,y\n0,1\ninf,2\n"), 3, Some("1 (t)"), "not finite");
        expect_data_error(parse("t,y\n0,1\nNaN,2\n"), 3, Some("1 (t)"), "required");
        expect_data_error(parse("t,y\n0,1\n1,2,3\n"), 3, None, "expected 2 columns");
        expect_data_error(parse("t,y\n0,1\n1\n"), 3, None, "expected 2 columns");
        expect_data_error(parse("t,y\n0,1\n1,abc\n"), 3, Some("2 (y)"), "cannot parse `abc`");
        expect_data_error(parse("t,y\n0,1\n1,inf\n"), 3, Some("2 (y)"), "not finite");
        expect_data_error(parse("time,y\n0,1\n"), 1, Some("1"), "first column must be `t`");
        expect_data_error(parse("t,y,y\n0,1,2\n"), 1, Some("3 (y)"), "duplicate");
        expect_data_error(parse_for("t,y,w\n0,1,2\n", &["y"]), 1, Some("3 (w)"), "unknown output `w`");
    }

    #[test]
    fn try_new_rejects_bad_shapes_and_times() {
        let names = vec!["y".to_string()];
        assert!(matches!(
            Dataset::try_new(names.clone(), vec![0.0], vec![]),
            Err(Error::DimensionMismatch { .. })
        ));
        assert!(Dataset::try_new(names.clone(), vec![1.0, 0.0], vec![vec![0.0], vec![0.0]]).is_err());
        assert!(Dataset::try_new(names.clone(), vec![0.0], vec![vec![0.0, 1.0]]).is_err());
        assert!(Dataset::try_new(names, vec![0.0], vec![vec![f64::INFINITY]]).is_err());
    }

    #[test]
    fn event_times_keep_every_measurement() {
        // Two measurements 1e-10 apart stay distinct; extras close to a measurement or to each
        // other are dropped; the maps are consistent.
        let meas = [1.0, 1.0 + 1e-10, 2.0];
        let e = EventTimes::merge(&meas, &[2.5, 0.0, 1.0 + 5e-11, 2.0, 2.5 + 1e-12, 1.5]);
        assert_eq!(e.times, vec![0.0, 1.0, 1.0 + 1e-10, 1.5, 2.0, 2.5]);
        assert_eq!(e.measurement, vec![None, Some(0), Some(1), None, Some(2), None]);
        assert_eq!(e.index_of_measurement, vec![1, 2, 4]);
        let empty = EventTimes::merge(&[], &[0.0, 1.0]);
        assert_eq!(empty.times, vec![0.0, 1.0]);
        assert!(empty.index_of_measurement.is_empty());
    }

    #[test]
    fn missing_file_is_an_io_error_naming_it() {
        let e = Dataset::read_csv("/nonexistent/dir/data.csv").unwrap_err();
        assert!(e.to_string().contains("/nonexistent/dir/data.csv"), "{e}");
    }
}
