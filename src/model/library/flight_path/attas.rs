//! The flight-test records of Jategaonkar, *Flight Vehicle System Identification* (2nd ed.,
//! AIAA, supplementary material `flt_data`): whitespace-separated ASCII, one row per sample,
//! the channels of the ATTAS aircraft in the columns of the book's channel list, in the units
//! recorded (degrees, feet), read into the measurement [`Dataset`] of
//! [`FlightPathObservation`](super::FlightPathObservation) in SI units.

use std::io::{BufRead, BufReader, Read};
use std::path::Path;

use super::FlightPathObservation;
use crate::data::Dataset;
use crate::{Error, Result};

/// Where each output of [`FlightPathObservation`] is in a flight-test record: 1-based column
/// numbers, and whether the column is in degrees (converted to radians) or feet (converted to
/// metres).
#[derive(Debug, Clone, PartialEq)]
pub struct FlightColumns {
    /// The time column (s).
    pub time: usize,
    /// Per output, in the order of [`FlightPathObservation::OUTPUTS`]: column number, channel
    /// name (for errors) and unit.
    pub outputs: [(usize, &'static str, Unit); 13],
}

/// The unit of a recorded channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Unit {
    /// Already SI (m/s, m/s²): taken as is.
    Si,
    /// Degrees or degrees per second: times π/180.
    Degrees,
    /// Feet: times 0.3048.
    Feet,
}

impl Unit {
    fn to_si(self, v: f64) -> f64 {
        match self {
            Unit::Si => v,
            Unit::Degrees => v.to_radians(),
            Unit::Feet => v * 0.3048,
        }
    }
}

impl FlightColumns {
    /// The ATTAS records `fAttas*.asc` (the channel list of the book's `README.txt`): time 1;
    /// VTASCG 15 (m/s); ALCG 13, BECG 14 (deg; the book's reconstruction takes them as the
    /// nose-boom α and β); PHI 10, THE 11, PSI 12 (deg); HQNH 16 (ft); PRGX 7, QRGY 8, RRGZ 9
    /// (deg/s); AXCG 2, AYCG 3, AZCG 4 (m/s²).
    pub const ATTAS: FlightColumns = FlightColumns {
        time: 1,
        outputs: [
            (15, "VTASCG", Unit::Si),
            (13, "ALCG", Unit::Degrees),
            (14, "BECG", Unit::Degrees),
            (10, "PHI", Unit::Degrees),
            (11, "THE", Unit::Degrees),
            (12, "PSI", Unit::Degrees),
            (16, "HQNH", Unit::Feet),
            (7, "PRGX", Unit::Degrees),
            (8, "QRGY", Unit::Degrees),
            (9, "RRGZ", Unit::Degrees),
            (2, "AXCG", Unit::Si),
            (3, "AYCG", Unit::Si),
            (4, "AZCG", Unit::Si),
        ],
    };

    /// The largest column number used.
    pub fn needed(&self) -> usize {
        self.outputs.iter().map(|o| o.0).fold(self.time, usize::max)
    }

    /// The channel name of 1-based column `col`, if it is used.
    fn name(&self, col: usize) -> Option<&'static str> {
        if col == self.time {
            return Some("T");
        }
        self.outputs.iter().find(|o| o.0 == col).map(|o| o.1)
    }
}

fn data_err(path: &Path, line: usize, column: Option<String>, reason: impl Into<String>) -> Error {
    Error::Data { path: path.to_path_buf(), line, column, reason: reason.into() }
}

/// Reads a flight-test record from `path` with the columns `columns` (see
/// [`read_flight_record_from`]).
///
/// # Errors
/// [`Error::Io`] if the file cannot be read; as [`read_flight_record_from`].
pub fn read_flight_record(path: impl AsRef<Path>, columns: &FlightColumns) -> Result<Dataset> {
    let path = path.as_ref();
    let file = std::fs::File::open(path).map_err(|source| Error::Io { path: path.to_path_buf(), source })?;
    read_flight_record_from(file, path, columns)
}

/// Parses a flight-test record: whitespace-separated numbers (Fortran-style exponents such as
/// `5.0e+001` included), one sample per line, blank lines skipped, every row with as many
/// columns as the first; into the measurement dataset of [`FlightPathObservation`] (columns
/// [`FlightPathObservation::OUTPUTS`], SI units) at the recorded times. `path` names the source
/// in errors.
///
/// # Errors
/// [`Error::Data`] naming the file, the line and (for a cell) the column number and channel
/// when: the file has no rows; the first row has fewer columns than `columns` needs; a later
/// row has a different number of columns (the last row with fewer: the file is truncated); a
/// cell is not a finite number; the time column is not strictly increasing.
pub fn read_flight_record_from<R: Read>(reader: R, path: &Path, columns: &FlightColumns) -> Result<Dataset> {
    let needed = columns.needed();
    let mut width: Option<usize> = None;
    let mut times: Vec<f64> = Vec::new();
    let mut values: Vec<Vec<f64>> = Vec::new();
    let mut lines = Vec::new();
    for (i, line) in BufReader::new(reader).lines().enumerate() {
        lines.push(line.map_err(|e| data_err(path, i + 1, None, format!("cannot read the line: {e}")))?);
    }
    let last_row = lines.iter().rposition(|l| !l.trim().is_empty());
    for (i, line) in lines.iter().enumerate() {
        let line_no = i + 1;
        let cells: Vec<&str> = line.split_whitespace().collect();
        if cells.is_empty() {
            continue;
        }
        let last = Some(i) == last_row;
        match width {
            None if cells.len() < needed => {
                return Err(data_err(
                    path,
                    line_no,
                    None,
                    format!(
                        "{} columns, but the flight record needs at least {needed} (column {needed} is {})",
                        cells.len(),
                        columns.name(needed).unwrap_or("?")
                    ),
                ))
            }
            None => width = Some(cells.len()),
            Some(w) if cells.len() < w && last => {
                return Err(data_err(
                    path,
                    line_no,
                    Some((cells.len() + 1).to_string()),
                    format!("the file ends after {} of {w} columns: it is truncated", cells.len()),
                ))
            }
            Some(w) if cells.len() != w => {
                return Err(data_err(
                    path,
                    line_no,
                    None,
                    format!("{} columns, but the first row has {w}", cells.len()),
                ))
            }
            Some(_) => {}
        }
        let cell = |col: usize| -> Result<f64> {
            let text = cells[col - 1];
            let column = Some(format!("{col} ({})", columns.name(col).unwrap_or("?")));
            match text.parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(v),
                Ok(_) => Err(data_err(path, line_no, column, format!("`{text}` is not finite"))),
                Err(_) => Err(data_err(path, line_no, column, format!("cannot parse `{text}` as a number"))),
            }
        };
        let t = cell(columns.time)?;
        if let Some(&prev) = times.last() {
            if t <= prev {
                return Err(data_err(
                    path,
                    line_no,
                    Some(format!("{} (T)", columns.time)),
                    format!("times must be strictly increasing: {t} follows {prev}"),
                ));
            }
        }
        let row = columns.outputs.iter().map(|&(col, _, unit)| cell(col).map(|v| unit.to_si(v)));
        values.push(row.collect::<Result<Vec<f64>>>()?);
        times.push(t);
    }
    if times.is_empty() {
        return Err(data_err(path, 1, None, "no data rows"));
    }
    let names = FlightPathObservation::OUTPUTS.iter().map(|s| s.to_string()).collect();
    Ok(Dataset { names, times, values })
}
