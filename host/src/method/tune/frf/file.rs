//! The measured frequency response's file: its points, the conditions it was
//! measured in (written in its header) and reading and writing it.

use super::*;

/// One measured frequency.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrfPoint {
    /// Frequency, Hz.
    pub f_hz: f64,
    /// Command → position sensor, µm/µm.
    pub x: Complex<f64>,
    /// Command → force reading, N/µm.
    pub force: Complex<f64>,
    /// Command → the force channel's dynamic part, N/µm.
    pub dynamic: Complex<f64>,
    /// Setpoint → position sensor, µm/V.
    pub x_per_v: Complex<f64>,
    /// Excitation amplitude, µm.
    pub excitation_um: f64,
    /// Ticks correlated.
    pub ticks: u32,
}

/// A CSV row.
#[derive(Debug, Serialize, Deserialize)]
struct Row {
    freq_hz: f64,
    x_re: f64,
    x_im: f64,
    force_re: f64,
    force_im: f64,
    dynamic_re: f64,
    dynamic_im: f64,
    x_per_v_re: f64,
    x_per_v_im: f64,
    excitation_um: f64,
    ticks: u32,
}

/// What the board ran while it measured a response (its status then).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrfConditions {
    /// The loop: open, closed (feedback and feedforward) or feedback alone.
    pub loop_mode: LoopMode,
    /// The active damping: on, off, or `None` where the model has none.
    pub damping: Option<bool>,
    /// The reference shaping: on, off, or `None` where the model has none.
    pub shaping: Option<bool>,
    /// The compensated (inverse FPI) drive, else the straight line.
    pub compensated: bool,
}

/// What the file's first line starts with.
pub(super) const CONDITIONS: &str = "# measured with:";

impl FrfConditions {
    /// The file's first line: `# measured with: loop=open damping=off
    /// shaping=none drive=compensated`.
    pub fn header(&self) -> String {
        let state = |v: Option<bool>| match v {
            Some(true) => "on",
            Some(false) => "off",
            None => "none",
        };
        format!(
            "{CONDITIONS} loop={} damping={} shaping={} drive={}",
            match self.loop_mode {
                LoopMode::Open => "open",
                LoopMode::Closed => "closed",
                LoopMode::FeedbackOnly => "feedback",
            },
            state(self.damping),
            state(self.shaping),
            if self.compensated {
                "compensated"
            } else {
                "uncompensated"
            }
        )
    }

    /// The conditions of a first line [`header`](Self::header) wrote; `None`
    /// for another line; an error naming the field for one it cannot read.
    pub fn parse(line: &str) -> Result<Option<Self>, String> {
        let Some(rest) = line.trim().strip_prefix(CONDITIONS) else {
            return Ok(None);
        };
        let mut c = FrfConditions {
            loop_mode: LoopMode::Open,
            damping: None,
            shaping: None,
            compensated: true,
        };
        let mut seen = 0;
        for field in rest.split_whitespace() {
            let (key, value) = field.split_once('=').unwrap_or((field, ""));
            let state = |v: &str| match v {
                "on" => Ok(Some(true)),
                "off" => Ok(Some(false)),
                "none" => Ok(None),
                _ => Err(format!("{key}={v}: on, off or none")),
            };
            match key {
                "loop" => {
                    c.loop_mode = match value {
                        "open" => LoopMode::Open,
                        "closed" => LoopMode::Closed,
                        "feedback" => LoopMode::FeedbackOnly,
                        v => return Err(format!("loop={v}: open, closed or feedback")),
                    }
                }
                "damping" => c.damping = state(value)?,
                "shaping" => c.shaping = state(value)?,
                "drive" => {
                    c.compensated = match value {
                        "compensated" => true,
                        "uncompensated" => false,
                        v => return Err(format!("drive={v}: compensated or uncompensated")),
                    }
                }
                _ => return Err(format!("{field}: not loop=, damping=, shaping= or drive=")),
            }
            seen += 1;
        }
        if seen < 4 {
            return Err("it needs loop=, damping=, shaping= and drive=".into());
        }
        Ok(Some(c))
    }

    /// Whether the response is the stage's own: the loop open, no damping
    /// acting.
    pub fn is_plant(&self) -> bool {
        self.loop_mode == LoopMode::Open && self.damping != Some(true)
    }
}

/// A response read from a file: its points and, where the file says them, the
/// conditions it was measured under.
#[derive(Debug, Clone, PartialEq)]
pub struct MeasuredFrf {
    /// The frequencies, as measured.
    pub points: Vec<FrfPoint>,
    /// What the board ran meanwhile (`None`: a file without the header line).
    pub conditions: Option<FrfConditions>,
}

/// Writes `points` measured under `conditions` as `FRF.csv` (atomically).
pub fn write_csv(path: &Path, points: &[FrfPoint], conditions: &FrfConditions) -> Result<()> {
    crate::output::write_atomic_with(path, |out| {
        writeln!(out, "{}", conditions.header())?;
        let mut w = csv::Writer::from_writer(out);
        for p in points {
            w.serialize(Row {
                freq_hz: p.f_hz,
                x_re: p.x.re,
                x_im: p.x.im,
                force_re: p.force.re,
                force_im: p.force.im,
                dynamic_re: p.dynamic.re,
                dynamic_im: p.dynamic.im,
                x_per_v_re: p.x_per_v.re,
                x_per_v_im: p.x_per_v.im,
                excitation_um: p.excitation_um,
                ticks: p.ticks,
            })
            .map_err(std::io::Error::other)?;
        }
        w.flush()
    })
}

/// Reads `FRF.csv` ([`write_csv`]); a bad row is named by its line and the
/// field at fault, a first line of conditions it cannot read by its field.
pub fn read_csv(path: &Path) -> Result<MeasuredFrf> {
    let shown = path.display();
    let bytes = crate::data::read_bytes(path)?;
    let text = String::from_utf8_lossy(&bytes);
    let first = text.lines().next().unwrap_or("");
    let conditions = FrfConditions::parse(first)
        .map_err(|e| anyhow::anyhow!("{shown}:1: {}: {e}", Quoted(first)))?;
    let mut r = csv::ReaderBuilder::new()
        .comment(Some(b'#'))
        .from_reader(text.as_bytes());
    let headers = r
        .headers()
        .with_context(|| format!("reading {shown}"))?
        .clone();
    let mut out = Vec::new();
    for record in r.records() {
        let record = record.with_context(|| format!("reading {shown}"))?;
        let line = record.position().map_or(0, |p| p.line());
        let row: Row = record
            .deserialize(Some(&headers))
            .with_context(|| format!("{shown}:{line}"))?;
        let values = [
            ("freq_hz", row.freq_hz),
            ("x_re", row.x_re),
            ("x_im", row.x_im),
            ("dynamic_re", row.dynamic_re),
            ("dynamic_im", row.dynamic_im),
        ];
        if let Some((field, v)) = values.iter().find(|(_, v)| !v.is_finite()) {
            bail!("{shown}:{line}: {field} = {v}: not a number");
        }
        if row.freq_hz.is_nan() || row.freq_hz <= 0.0 {
            bail!(
                "{shown}:{line}: freq_hz = {}: must be positive",
                Num(row.freq_hz)
            );
        }
        out.push(FrfPoint {
            f_hz: row.freq_hz,
            x: Complex::new(row.x_re, row.x_im),
            force: Complex::new(row.force_re, row.force_im),
            dynamic: Complex::new(row.dynamic_re, row.dynamic_im),
            x_per_v: Complex::new(row.x_per_v_re, row.x_per_v_im),
            excitation_um: row.excitation_um,
            ticks: row.ticks,
        });
    }
    if out.len() < 8 {
        bail!(
            "{shown}: {} frequencies: at least 8 are needed to fit the dynamics",
            out.len()
        );
    }
    Ok(MeasuredFrf {
        points: out,
        conditions,
    })
}
