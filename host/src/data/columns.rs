//! Files whose columns are named per axis (`voltage_V@x`, `x_pea_um@y`, …): the
//! several-axis method's FEM grids, drives and recordings.

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::path::Path;

use piezo_sim::axes::AXIS_NAMES;

use crate::data::{for_each_record_at, open, DataError};

/// Named columns of a file, read whole.
#[derive(Debug, Clone, PartialEq)]
pub struct Columns {
    /// The line of each row in the file.
    pub lines: Vec<u64>,
    /// One vector per requested column, in the order asked.
    pub values: Vec<Vec<f64>>,
}

/// Reads `names` (every one required; other columns ignored, but every column
/// must hold numbers); errors name the file, line and column.
pub fn read_named_columns(path: &Path, names: &[&str]) -> Result<Columns, DataError> {
    let mut c = Columns {
        lines: Vec::new(),
        values: vec![Vec::new(); names.len()],
    };
    for_each_record_at(
        path,
        open(path)?,
        names,
        |row: BTreeMap<String, f64>, line| {
            c.lines.push(line);
            for (v, n) in c.values.iter_mut().zip(names) {
                v.push(row[*n]);
            }
        },
    )?;
    Ok(c)
}

/// The axes a file has columns `quantity@x`, `quantity@y`, … for: 1 to 3,
/// named in order from `x`.
pub fn axes_in_header(path: &Path, quantity: &str) -> Result<usize, DataError> {
    let mut first = String::new();
    BufReader::new(open(path)?)
        .read_line(&mut first)
        .map_err(|e| crate::data::data_error(path, e))?;
    let header: Vec<&str> = first.trim().split(',').map(str::trim).collect();
    let has = |i: usize| header.contains(&format!("{quantity}@{}", AXIS_NAMES[i]).as_str());
    let axes = (0..AXIS_NAMES.len()).take_while(|&i| has(i)).count();
    if let Some(skipped) = (axes..AXIS_NAMES.len()).find(|&i| has(i)) {
        return Err(DataError::at(
            path,
            1,
            &format!("{quantity}@{}", AXIS_NAMES[skipped]),
            format!(
                "axes are named in order from x: {quantity}@{} is missing",
                AXIS_NAMES[axes]
            ),
        ));
    }
    if axes == 0 {
        return Err(DataError::at(
            path,
            1,
            &format!("{quantity}@x"),
            format!(
                "missing in the header: a file of several axes names its columns \
                 {quantity}@x, {quantity}@y[, {quantity}@z]"
            ),
        ));
    }
    Ok(axes)
}
