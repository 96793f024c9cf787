//! Reading the recorded datasets: CSV through `csv` + `serde`, gzip transparently.
//!
//! CSV files are read as a stream ([`open`]: gunzipped on the fly, within
//! [`ReadLimits`]) and their records go one at a time ([`for_each_record`])
//! into the columns: the CSV readers hold neither a file's whole content nor a
//! list of its rows.
//!
//! Every error names the file, the line (1-based, header = line 1) and the column,
//! e.g. `stage-a/fem.csv:17: column x_pea_um: "1,5" is not a number`.

pub mod columns;
pub mod fem;
pub mod toml_file;

use std::collections::BTreeMap;
use std::fmt;
use std::fs::File;
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

use flate2::read::MultiGzDecoder;
use serde::de::DeserializeOwned;
use serde::Deserialize;

pub use piezo_sim::quote::{clip, Quoted};

/// A problem with an input file, located as precisely as possible.
#[derive(Debug, Clone, PartialEq)]
pub struct DataError {
    /// The file.
    pub file: PathBuf,
    /// 1-based line (the header is line 1), when the problem is on one line.
    pub line: Option<u64>,
    /// The column's name, when the problem is in one field.
    pub column: Option<String>,
    /// What is wrong.
    pub message: String,
}

impl DataError {
    pub(crate) fn file(file: &Path, message: impl Into<String>) -> Self {
        Self {
            file: file.to_path_buf(),
            line: None,
            column: None,
            message: message.into(),
        }
    }
    pub(crate) fn at(file: &Path, line: u64, column: &str, message: impl Into<String>) -> Self {
        Self {
            file: file.to_path_buf(),
            line: Some(line),
            column: Some(column.to_string()),
            message: message.into(),
        }
    }
}

impl fmt::Display for DataError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if let Some(l) = self.line {
            write!(f, ":{l}")?;
        }
        if let Some(c) = &self.column {
            write!(f, ": column {c}")?;
        }
        write!(f, ": {}", self.message)
    }
}

impl std::error::Error for DataError {}

pub use piezo_sim::quote::Num;

/// The project's root (the `piezo-fpi` package, above `host/`).
pub fn project_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from(".."))
}

/// A path relative to the project root when it lies inside it (provenance that
/// means the same on every machine), else as given.
pub fn project_relative(p: &Path) -> String {
    let root = project_root();
    let abs = if p.is_absolute() {
        p.to_path_buf()
    } else {
        std::env::current_dir()
            .map(|d| d.join(p))
            .unwrap_or_else(|_| p.to_path_buf())
    };
    match abs.strip_prefix(&root) {
        Ok(r) => r.display().to_string(),
        Err(_) => p.display().to_string(),
    }
}

/// Where the project's copies of the datasets live (`tests-host/data`, with the
/// harness that runs the core against them; their provenance in its README).
pub fn data_dir() -> PathBuf {
    project_root().join("tests-host").join("data")
}

/// A dataset file by its path under `data/` without `.gz` (`"stage-a/fem.csv"`).
pub fn dataset(relative: &str) -> PathBuf {
    let plain = data_dir().join(relative);
    if plain.exists() {
        plain
    } else {
        data_dir().join(format!("{relative}.gz"))
    }
}

/// All dataset files of a folder under `data/`, sorted, `.gz` stripped from nothing.
pub fn datasets_in(folder: &str) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(data_dir().join(folder))
        .map(|d| {
            d.filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| {
                    let n = p.to_string_lossy();
                    n.ends_with(".csv") || n.ends_with(".csv.gz")
                })
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// Most bytes an input file may hold once decompressed: 1 GiB (the largest dataset
/// is 2.5 MB).
pub const MAX_BYTES: u64 = 1 << 30;

/// Most bytes a gzip file may expand to per compressed byte, checked once more than
/// [`RATIO_FROM`] bytes came out. The datasets expand 1–11 times; a recording's
/// strictly increasing time column alone keeps a CSV far below 100; gzip bombs
/// expand about 1000 times.
pub const MAX_RATIO: u64 = 100;

/// Decompressed size from which [`MAX_RATIO`] applies, bytes (16 MiB).
pub const RATIO_FROM: u64 = 16 << 20;

/// Limits on what [`read_bytes_within`] and [`open_within`] read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReadLimits {
    /// Most bytes of content (decompressed), bytes.
    pub max_bytes: u64,
    /// Most decompressed bytes per compressed byte, beyond `ratio_from` bytes.
    pub max_ratio: u64,
    /// Decompressed size from which `max_ratio` applies, bytes.
    pub ratio_from: u64,
}

impl ReadLimits {
    /// The limits of every input file: [`MAX_BYTES`], [`MAX_RATIO`], [`RATIO_FROM`].
    pub const INPUT: Self = Self {
        max_bytes: MAX_BYTES,
        max_ratio: MAX_RATIO,
        ratio_from: RATIO_FROM,
    };
}

/// The whole content of a file, gunzipped if its name ends in `.gz` (every member
/// of a multi-member file), within [`ReadLimits::INPUT`].
pub fn read_bytes(path: &Path) -> Result<Vec<u8>, DataError> {
    read_bytes_within(path, ReadLimits::INPUT)
}

/// [`read_bytes`] within other limits: stops reading, with an error naming the
/// file, as soon as the content exceeds `limits` (a gzip bomb is never expanded
/// in full).
pub fn read_bytes_within(path: &Path, limits: ReadLimits) -> Result<Vec<u8>, DataError> {
    let mut content = open_within(path, limits)?;
    let mut out = Vec::new();
    match content.read_to_end(&mut out) {
        Ok(_) => Ok(out),
        Err(e) => Err(data_error(path, e)),
    }
}

/// The content of a file as a stream, gunzipped if its name ends in `.gz`, within
/// [`ReadLimits::INPUT`]: what [`read_bytes`] returns, never held whole.
pub fn open(path: &Path) -> Result<Content, DataError> {
    open_within(path, ReadLimits::INPUT)
}

/// [`open`] within other limits: a read that takes the content beyond `limits`
/// fails with the [`DataError`] [`read_bytes_within`] gives (inside the
/// `io::Error`; [`data_error`] takes it out), and so does every later read.
pub fn open_within(path: &Path, limits: ReadLimits) -> Result<Content, DataError> {
    let file = File::open(path).map_err(|e| DataError::file(path, format!("cannot open: {e}")))?;
    let counted = Counted {
        inner: BufReader::new(file),
        bytes: 0,
    };
    let source = if path.extension().is_some_and(|e| e == "gz") {
        Source::Gz(MultiGzDecoder::new(counted))
    } else {
        Source::Plain(counted)
    };
    Ok(Content {
        path: path.to_path_buf(),
        source,
        limits,
        size: 0,
        failed: None,
    })
}

/// A file's content, read through [`open`] or [`open_within`].
pub struct Content {
    path: PathBuf,
    source: Source,
    limits: ReadLimits,
    /// Bytes of content returned so far.
    size: u64,
    /// The error that ended reading, returned again by every later read.
    failed: Option<DataError>,
}

impl fmt::Debug for Content {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Content")
            .field("path", &self.path)
            .field("limits", &self.limits)
            .field("size", &self.size)
            .field("failed", &self.failed)
            .finish_non_exhaustive()
    }
}

enum Source {
    Plain(Counted<BufReader<File>>),
    Gz(MultiGzDecoder<Counted<BufReader<File>>>),
}

impl Content {
    /// Compressed bytes read from the file so far (0: not compressed).
    fn packed(&self) -> u64 {
        match &self.source {
            Source::Plain(_) => 0,
            Source::Gz(gz) => gz.get_ref().bytes,
        }
    }

    /// Records `e` as the end of reading and returns it as an `io::Error`.
    fn fail(&mut self, e: DataError) -> std::io::Error {
        self.failed = Some(e.clone());
        std::io::Error::other(e)
    }

    /// The error a read past the limits gives, if the content's `size` is past them.
    fn beyond_limits(&self) -> Option<DataError> {
        let (size, limits) = (self.size, self.limits);
        if size > limits.max_bytes {
            return Some(DataError::file(
                &self.path,
                format!(
                    "more than {} bytes of content: refusing to read further (no dataset is \
                     that large; a gzip bomb?)",
                    limits.max_bytes
                ),
            ));
        }
        let packed = self.packed();
        if packed > 0 && size > limits.ratio_from && size > packed.saturating_mul(limits.max_ratio)
        {
            return Some(DataError::file(
                &self.path,
                format!(
                    "{packed} compressed bytes expand to more than {size}: a ratio above \
                     {}:1, which no CSV recording has (a gzip bomb?); refusing to read further",
                    limits.max_ratio
                ),
            ));
        }
        None
    }
}

impl Read for Content {
    /// Reads on, checking the size (and for a gzip file the expansion ratio) after
    /// each read; errors are [`DataError`]s naming the file.
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if let Some(e) = &self.failed {
            return Err(std::io::Error::other(e.clone()));
        }
        let n = loop {
            let r = match &mut self.source {
                Source::Plain(p) => p.read(buf),
                Source::Gz(gz) => gz.read(buf),
            };
            match r {
                Ok(n) => break n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => {
                    let e = DataError::file(&self.path, format!("cannot read: {e}"));
                    return Err(self.fail(e));
                }
            }
        };
        self.size += n as u64;
        match self.beyond_limits() {
            Some(e) => Err(self.fail(e)),
            None => Ok(n),
        }
    }
}

/// A reader that counts the bytes read through it.
struct Counted<R> {
    inner: R,
    bytes: u64,
}

impl<R: Read> Read for Counted<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.bytes += n as u64;
        Ok(n)
    }
}

/// The [`DataError`] an `io::Error` of a [`Content`] carries, or one naming
/// `path` ("cannot read: …").
pub fn data_error(path: &Path, e: std::io::Error) -> DataError {
    match e.get_ref().and_then(|i| i.downcast_ref::<DataError>()) {
        Some(d) => d.clone(),
        None => DataError::file(path, format!("cannot read: {e}")),
    }
}

/// The [`DataError`] a CSV error carries: a [`Content`]'s read that failed.
fn carried(e: &csv::Error) -> Option<DataError> {
    match e.kind() {
        csv::ErrorKind::Io(e) => e.get_ref()?.downcast_ref::<DataError>().cloned(),
        _ => None,
    }
}

/// Records whose every number must be finite; names the first that is not.
pub trait Finite {
    /// The column of the first non-finite field, if any.
    fn non_finite(&self) -> Option<&str>;
}

/// A row read by column name (the columns a file's header names).
impl Finite for BTreeMap<String, f64> {
    fn non_finite(&self) -> Option<&str> {
        self.iter()
            .find(|(_, v)| !v.is_finite())
            .map(|(k, _)| k.as_str())
    }
}

/// Reads a CSV file with a header into records of `T` (columns by name; extra
/// columns are ignored). Checks that every column `T` needs is present and every
/// number is finite.
pub fn read_csv<T: DeserializeOwned + Finite>(
    path: &Path,
    columns: &[&str],
) -> Result<Vec<T>, DataError> {
    collect_csv(path, open(path)?, columns)
}

/// [`read_csv`] on the bytes of a file (`path` names it in errors): the same
/// reader, [`for_each_record`], on a byte slice.
pub fn parse_csv<T: DeserializeOwned + Finite>(
    path: &Path,
    bytes: &[u8],
    columns: &[&str],
) -> Result<Vec<T>, DataError> {
    collect_csv(path, bytes, columns)
}

fn collect_csv<T: DeserializeOwned + Finite>(
    path: &Path,
    content: impl Read,
    columns: &[&str],
) -> Result<Vec<T>, DataError> {
    let mut out = Vec::new();
    for_each_record(path, content, columns, |v: T| out.push(v))?;
    Ok(out)
}

/// The CSV reader of every dataset: reads `content` (a [`Content`], a byte
/// slice, …) record by record, checks the header (no column twice, every one of
/// `columns` present), deserializes each record into a `T` (columns by name;
/// extra columns ignored), checks that its numbers are finite and hands it to
/// `each`. Returns the number of records; none is an error ("no data rows").
/// Holds one record at a time.
pub fn for_each_record<T: DeserializeOwned + Finite>(
    path: &Path,
    content: impl Read,
    columns: &[&str],
    mut each: impl FnMut(T),
) -> Result<u64, DataError> {
    for_each_record_at(path, content, columns, |v, _| each(v))
}

/// [`for_each_record`], handing each record its line in the file.
pub fn for_each_record_at<T: DeserializeOwned + Finite>(
    path: &Path,
    content: impl Read,
    columns: &[&str],
    mut each: impl FnMut(T, u64),
) -> Result<u64, DataError> {
    let mut rdr = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .buffer_capacity(1 << 16)
        .from_reader(content);
    let headers = rdr
        .headers()
        .map_err(|e| {
            carried(&e)
                .unwrap_or_else(|| DataError::file(path, format!("cannot read the header: {e}")))
        })?
        .clone();
    duplicate_column(path, &headers)?;
    let missing: Vec<&str> = columns
        .iter()
        .filter(|c| !headers.iter().any(|h| h == **c))
        .copied()
        .collect();
    if !missing.is_empty() {
        return Err(DataError {
            file: path.to_path_buf(),
            line: Some(1),
            column: Some(missing.join(", ")),
            message: format!(
                "missing in the header (expected {}; found {})",
                columns.join(","),
                clip(&headers.iter().collect::<Vec<_>>().join(","))
            ),
        });
    }
    let mut rows = 0u64;
    let mut rec = csv::StringRecord::new();
    while rdr.read_record(&mut rec).map_err(|e| csv_error(path, e))? {
        let line = rec.position().map_or(0, |p| p.line());
        let value: T = rec.deserialize(Some(&headers)).map_err(|e| {
            let field = match e.kind() {
                csv::ErrorKind::Deserialize { err, .. } => err.field(),
                _ => None,
            };
            let column = field
                .and_then(|i| headers.get(i as usize))
                .unwrap_or("?")
                .to_string();
            let raw = field.and_then(|i| rec.get(i as usize)).unwrap_or("");
            DataError {
                file: path.to_path_buf(),
                line: Some(line),
                column: Some(column),
                message: format!("{} is not a number", Quoted(raw)),
            }
        })?;
        if let Some(c) = value.non_finite() {
            let i = headers.iter().position(|h| h == c).unwrap_or(0);
            return Err(DataError::at(
                path,
                line,
                c,
                format!(
                    "{} is not a finite number",
                    Quoted(rec.get(i).unwrap_or(""))
                ),
            ));
        }
        each(value, line);
        rows += 1;
    }
    if rows == 0 {
        return Err(DataError::file(path, "no data rows"));
    }
    Ok(rows)
}

/// Refuses a header that names a column twice (by name, on line 1; unnamed
/// columns aside).
fn duplicate_column(path: &Path, headers: &csv::StringRecord) -> Result<(), DataError> {
    for (j, h) in headers.iter().enumerate().filter(|(_, h)| !h.is_empty()) {
        if let Some(i) = headers.iter().take(j).position(|g| g == h) {
            return Err(DataError::at(
                path,
                1,
                &clip(h),
                format!(
                    "appears twice in the header (fields {} and {}): which one holds the data?",
                    i + 1,
                    j + 1
                ),
            ));
        }
    }
    Ok(())
}

fn csv_error(path: &Path, e: csv::Error) -> DataError {
    if let Some(d) = carried(&e) {
        return d;
    }
    let line = e.position().map(|p| p.line());
    let message = match e.kind() {
        csv::ErrorKind::UnequalLengths {
            expected_len, len, ..
        } => {
            format!("{len} fields where the header has {expected_len}")
        }
        _ => e.to_string(),
    };
    DataError {
        file: path.to_path_buf(),
        line,
        column: None,
        message,
    }
}

/// Checks that a column is strictly increasing; names the first line that is not.
pub fn strictly_increasing(path: &Path, column: &str, values: &[f64]) -> Result<(), DataError> {
    for (i, w) in values.windows(2).enumerate() {
        if w[1] <= w[0] {
            // Data row i + 1 (0-based) is on line i + 3 (header + 1-based).
            return Err(DataError::at(
                path,
                i as u64 + 3,
                column,
                format!(
                    "{} does not increase (previous row {})",
                    Num(w[1]),
                    Num(w[0])
                ),
            ));
        }
    }
    Ok(())
}

macro_rules! finite_record {
    ($ty:ident { $($field:ident : $col:literal),* $(,)? }) => {
        impl Finite for $ty {
            fn non_finite(&self) -> Option<&str> {
                $( if !self.$field.is_finite() { return Some($col); } )*
                None
            }
        }
    };
}

/// One sample of a preload-rig recording (`pea-rig/`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
pub struct RigRow {
    /// Time, s.
    pub t_s: f64,
    /// Commanded voltage, V.
    #[serde(rename = "voltage_V")]
    pub voltage_v: f64,
    /// Preload on the stack, N.
    #[serde(rename = "force_N")]
    pub force_n: f64,
    /// Stack extension, µm (zeroed at t = 0).
    pub displacement_um: f64,
}
finite_record!(RigRow {
    t_s: "t_s",
    voltage_v: "voltage_V",
    force_n: "force_N",
    displacement_um: "displacement_um"
});

/// One sample of a stage recording (`stage-a/`; extra columns ignored).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
pub struct StageRow {
    /// Time, s.
    pub t_s: f64,
    /// Commanded voltage, V.
    #[serde(rename = "voltage_V")]
    pub voltage_v: f64,
    /// Force between stack and hinge, N.
    #[serde(rename = "force_N")]
    pub force_n: f64,
    /// Stage output, µm (zeroed at t = 0).
    pub x_fhps_um: f64,
}
finite_record!(StageRow {
    t_s: "t_s",
    voltage_v: "voltage_V",
    force_n: "force_N",
    x_fhps_um: "x_fhps_um"
});

/// One sample of a drive (`t_s,voltage_V`; extra columns ignored).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
struct DriveRow {
    t_s: f64,
    #[serde(rename = "voltage_V")]
    voltage_v: f64,
}
finite_record!(DriveRow {
    t_s: "t_s",
    voltage_v: "voltage_V"
});

/// Reads a drive file: time (strictly increasing) and voltage.
pub fn read_drive(path: &Path) -> Result<(Vec<f64>, Vec<f64>), DataError> {
    let (mut t, mut u) = (Vec::new(), Vec::new());
    for_each_record(path, open(path)?, &["t_s", "voltage_V"], |r: DriveRow| {
        t.push(r.t_s);
        u.push(r.voltage_v);
    })?;
    strictly_increasing(path, "t_s", &t)?;
    Ok((t, u))
}

/// One point of a trajectory to stream (`x_ref_um`; extra columns ignored).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
struct PointRow {
    x_ref_um: f64,
}
finite_record!(PointRow {
    x_ref_um: "x_ref_um"
});

/// Reads column `x_ref_um` of a CSV (a trajectory for `fpi board stream`), µm;
/// at least one point.
pub fn read_points(path: &Path) -> Result<Vec<f64>, DataError> {
    let mut x = Vec::new();
    for_each_record(path, open(path)?, &["x_ref_um"], |r: PointRow| {
        x.push(r.x_ref_um)
    })?;
    if x.is_empty() {
        return Err(DataError::file(path, "no points"));
    }
    Ok(x)
}

/// One sample of a target trajectory (`t_s,x_fhps_um`; extra columns ignored).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
struct TargetRow {
    t_s: f64,
    x_fhps_um: f64,
}
finite_record!(TargetRow {
    t_s: "t_s",
    x_fhps_um: "x_fhps_um"
});

/// Reads a target trajectory: time (strictly increasing) and stage position.
pub fn read_target(path: &Path) -> Result<(Vec<f64>, Vec<f64>), DataError> {
    let (mut t, mut x) = (Vec::new(), Vec::new());
    for_each_record(path, open(path)?, &["t_s", "x_fhps_um"], |r: TargetRow| {
        t.push(r.t_s);
        x.push(r.x_fhps_um);
    })?;
    strictly_increasing(path, "t_s", &t)?;
    Ok((t, x))
}

/// One point of an FEM export (`fem.csv`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
pub struct FemRow {
    /// Prescribed stack extension, µm.
    pub x_pea_um: f64,
    /// Reaction (pre)load on the stack, N.
    #[serde(rename = "preload_N")]
    pub preload_n: f64,
    /// Stage output, µm.
    pub x_fhps_um: f64,
}
finite_record!(FemRow {
    x_pea_um: "x_pea_um",
    preload_n: "preload_N",
    x_fhps_um: "x_fhps_um"
});

/// A recording of a voltage drive, by column: a preload rig's ([`read_rig`]: `x`
/// the stack extension) or a stage's ([`read_stage`]: `x` the stage output).
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    /// Source file.
    pub path: PathBuf,
    /// Time, s.
    pub t: Vec<f64>,
    /// Commanded voltage, V.
    pub u: Vec<f64>,
    /// Force on the stack, N.
    pub f: Vec<f64>,
    /// Stack extension (rig) or stage output (stage), µm.
    pub x: Vec<f64>,
}

/// A preload-rig recording: `x` is the stack extension.
pub type Rig = Recording;

/// A stage recording: `x` is the stage output.
pub type StageRun = Recording;

/// A row of a recording: its four columns by name, the last naming what `x` is.
trait RecordingRow: DeserializeOwned + Finite {
    /// Time, voltage, force and `x`.
    const COLUMNS: [&'static str; 4];
    /// The row's values in the order of [`COLUMNS`](Self::COLUMNS).
    fn values(&self) -> [f64; 4];
}

impl RecordingRow for RigRow {
    const COLUMNS: [&'static str; 4] = ["t_s", "voltage_V", "force_N", "displacement_um"];
    fn values(&self) -> [f64; 4] {
        [self.t_s, self.voltage_v, self.force_n, self.displacement_um]
    }
}

impl RecordingRow for StageRow {
    const COLUMNS: [&'static str; 4] = ["t_s", "voltage_V", "force_N", "x_fhps_um"];
    fn values(&self) -> [f64; 4] {
        [self.t_s, self.voltage_v, self.force_n, self.x_fhps_um]
    }
}

/// Reads a recording of rows `R`, record by record straight into the columns (the
/// content is never held whole); time strictly increasing.
fn read_recording<R: RecordingRow>(path: &Path) -> Result<Recording, DataError> {
    let mut r = Recording {
        path: path.to_path_buf(),
        t: Vec::new(),
        u: Vec::new(),
        f: Vec::new(),
        x: Vec::new(),
    };
    for_each_record(path, open(path)?, &R::COLUMNS, |row: R| {
        let [t, u, f, x] = row.values();
        r.t.push(t);
        r.u.push(u);
        r.f.push(f);
        r.x.push(x);
    })?;
    strictly_increasing(path, "t_s", &r.t)?;
    Ok(r)
}

/// Reads a `t_s,voltage_V,force_N,displacement_um` file (a preload rig's).
pub fn read_rig(path: &Path) -> Result<Rig, DataError> {
    read_recording::<RigRow>(path)
}

/// Reads a `t_s,voltage_V,force_N,x_fhps_um[,…]` file (a stage's).
pub fn read_stage(path: &Path) -> Result<StageRun, DataError> {
    read_recording::<StageRow>(path)
}

/// An FEM export, by column.
#[derive(Debug, Clone, PartialEq)]
pub struct Fem {
    /// Source file.
    pub path: PathBuf,
    /// Stack extension, µm (strictly increasing).
    pub x_pea: Vec<f64>,
    /// Preload, N.
    pub preload: Vec<f64>,
    /// Stage output, µm.
    pub x_fhps: Vec<f64>,
}

/// Reads and validates a `x_pea_um,preload_N,x_fhps_um` file: finite values,
/// strictly increasing `x_pea_um`, at least two points.
pub fn read_fem(path: &Path) -> Result<Fem, DataError> {
    let mut fem = Fem {
        path: path.to_path_buf(),
        x_pea: Vec::new(),
        preload: Vec::new(),
        x_fhps: Vec::new(),
    };
    let columns = ["x_pea_um", "preload_N", "x_fhps_um"];
    let rows = for_each_record(path, open(path)?, &columns, |row: FemRow| {
        fem.x_pea.push(row.x_pea_um);
        fem.preload.push(row.preload_n);
        fem.x_fhps.push(row.x_fhps_um);
    })?;
    if rows < 2 {
        return Err(DataError::file(
            path,
            "an FEM table needs at least two points",
        ));
    }
    strictly_increasing(path, "x_pea_um", &fem.x_pea)?;
    Ok(fem)
}

/// The micromanipulator recording: command (V, column 1) and sensor (µm, column 5).
#[derive(Debug, Clone, PartialEq)]
pub struct Micromanipulator {
    /// Source file.
    pub path: PathBuf,
    /// Amplifier input, V.
    pub u: Vec<f64>,
    /// Capacitive sensor, µm (as recorded).
    pub sensor: Vec<f64>,
}

/// Reads the tab-separated, header-less `Model_Vi_Do.dat`.
pub fn read_micromanipulator(path: &Path) -> Result<Micromanipulator, DataError> {
    let bytes = read_bytes(path)?;
    let text = String::from_utf8_lossy(&bytes);
    let (mut u, mut sensor) = (Vec::new(), Vec::new());
    for (i, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split('\t').collect();
        let ln = i as u64 + 1;
        let get = |k: usize| -> Result<f64, DataError> {
            let col = format!("{}", k + 1);
            let raw = fields
                .get(k)
                .ok_or_else(|| DataError::at(path, ln, &col, "missing field"))?;
            let v: f64 = raw.trim().parse().map_err(|_| {
                DataError::at(path, ln, &col, format!("{} is not a number", Quoted(raw)))
            })?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(DataError::at(
                    path,
                    ln,
                    &col,
                    format!("{} is not finite", Quoted(raw)),
                ))
            }
        };
        u.push(get(0)?);
        sensor.push(get(4)?);
    }
    Ok(Micromanipulator {
        path: path.to_path_buf(),
        u,
        sensor,
    })
}
