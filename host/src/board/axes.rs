//! A board of several axes as one: its model file of several axes
//! ([`AxesModel`]: each axis's model and the coupling) loaded whole
//! ([`load`]), and autotune of every axis and the coupling ([`autotune()`]),
//! which writes that file.

use anyhow::{bail, Context, Result};
use piezo_fpi::decoupling::Decoupling;
use piezo_sim::axes::AXIS_NAMES;
use piezo_sim::file::{AxesModel, FirmwareModel, AXES_FORMAT};

use super::autotune::{self, Autotune};
use super::client::{axis_name, Client};
use super::decoupling::{self, Measured};
use crate::method::tune::TuneOptions;

/// Refuses a file of `file_axes` axes on the board `c`, naming both.
fn same_axes(c: &Client, file_axes: usize) -> Result<()> {
    let n = usize::from(c.hello().axes);
    if n != file_axes {
        bail!(
            "the model file has {file_axes} axes ({}) and the board {n}: a file of several axes \
             loads onto a board of as many",
            AXIS_NAMES[..file_axes.min(AXIS_NAMES.len())].join(", ")
        );
    }
    Ok(())
}

/// Loads `file` whole onto the board `c`: every axis parked, each axis's
/// model uploaded to it (`store`: x's also into flash, which keeps the first
/// axis's model only), then the decoupling made of its coupling. Every
/// image is made before anything is sent. `progress` hears each axis's
/// model as it runs. The addressed axis is kept.
pub fn load(
    c: &mut Client,
    file: &AxesModel,
    store: bool,
    mut progress: impl FnMut(u8, u32),
) -> Result<()> {
    let models = file.models();
    same_axes(c, models.len())?;
    let images = models
        .iter()
        .zip(AXIS_NAMES)
        .map(|(m, name)| m.image().map_err(|e| anyhow::anyhow!("[{name}]: {e}")))
        .collect::<Result<Vec<_>>>()?;
    let d = file.decoupling().map_err(anyhow::Error::msg)?;
    let here = c.axis();
    let run = load_on(c, &images, &d, store, &mut progress);
    c.on_axis(here)?;
    run
}

/// [`load`] once its images and decoupling are made.
fn load_on(
    c: &mut Client,
    images: &[Vec<u8>],
    d: &Decoupling<{ decoupling::MAX_AXES }>,
    store: bool,
    progress: &mut dyn FnMut(u8, u32),
) -> Result<()> {
    c.on_axis(0)?;
    c.park()?;
    for (i, image) in images.iter().enumerate() {
        let axis = i as u8;
        c.on_axis(axis)?;
        let tick = c
            .upload(image, store && axis == 0, |_| {})
            .with_context(|| format!("loading axis {}'s model", axis_name(axis)))?;
        progress(axis, tick);
    }
    decoupling::set(c, d).context("setting the decoupling")?;
    Ok(())
}

/// What autotune of every axis and the coupling did.
#[derive(Debug, Clone)]
pub struct AxesAutotune {
    /// Each axis's autotune, in axis order.
    pub axes: Vec<Autotune>,
    /// The coupling measured with the axes tuned, and the decoupling set.
    pub coupling: Measured,
    /// The file of several axes: each axis's tuned model and the coupling.
    pub file: AxesModel,
}

/// Autotune of every axis of the board `c` (each from its model in
/// `models`, which it must run: [`autotune::run_keeping`]), then the
/// coupling measured with the axes tuned ([`decoupling::measure`]) and the
/// decoupling set. `keep` hears the file of several axes before the tuning is
/// left running: where it fails, as where anything else fails, every axis
/// is put back to the model it ran and the decoupling is off. The board is
/// left parked; `store` also keeps x's tuned model in flash.
pub fn autotune(
    c: &mut Client,
    models: &[FirmwareModel],
    tune: &TuneOptions,
    settings: (&autotune::Settings, &decoupling::Settings),
    store: bool,
    keep: &mut dyn FnMut(&AxesModel) -> Result<()>,
    mut progress: impl FnMut(&str),
) -> Result<AxesAutotune> {
    same_axes(c, models.len())?;
    if models.len() < 2 {
        bail!("the board has one axis: `fpi board autotune` tunes it as it is");
    }
    let here = c.axis();
    let run = tune_every_axis(c, models, tune, settings, keep, &mut progress);
    let put_back = match &run {
        Ok(_) => Ok(()),
        Err(_) => put_back(c, models),
    };
    let stored = match (&run, store) {
        (Ok(a), true) => store_first(c, &a.file.x),
        _ => Ok(()),
    };
    c.on_axis(here)?;
    let a = run?;
    put_back?;
    stored?;
    Ok(a)
}

/// Each axis tuned in turn, the coupling measured, the file made and kept.
fn tune_every_axis(
    c: &mut Client,
    models: &[FirmwareModel],
    tune: &TuneOptions,
    (settings, coupling): (&autotune::Settings, &decoupling::Settings),
    keep: &mut dyn FnMut(&AxesModel) -> Result<()>,
    progress: &mut dyn FnMut(&str),
) -> Result<AxesAutotune> {
    let mut axes = Vec::with_capacity(models.len());
    for (i, fw) in models.iter().enumerate() {
        let axis = i as u8;
        c.on_axis(axis)?;
        c.park()?;
        progress(&format!("axis {}:", axis_name(axis)));
        let a = autotune::run(c, fw, tune, settings, false, &mut *progress)
            .with_context(|| format!("autotune of axis {}", axis_name(axis)))?;
        axes.push(a);
    }
    progress("the coupling: each axis moved while the others hold");
    let tuned: Vec<FirmwareModel> = axes.iter().map(|a| a.model.clone()).collect();
    let coupling = decoupling::measure(c, &tuned, coupling)?;
    let mut tuned = tuned.into_iter();
    let (Some(x), Some(y)) = (tuned.next(), tuned.next()) else {
        bail!("a board of several axes has two at least");
    };
    let file = AxesModel {
        format: AXES_FORMAT.into(),
        coupling: coupling.coupling.clone(),
        x,
        y,
        z: tuned.next(),
    };
    keep(&file)?;
    Ok(AxesAutotune {
        axes,
        coupling,
        file,
    })
}

/// Every axis back to the model it ran (`models`), the decoupling off, the
/// board parked.
fn put_back(c: &mut Client, models: &[FirmwareModel]) -> Result<()> {
    c.on_axis(0)?;
    c.park()?;
    decoupling::set(c, &Decoupling::NONE)?;
    for (i, fw) in models.iter().enumerate() {
        c.on_axis(i as u8)?;
        let image = fw.image().map_err(anyhow::Error::msg)?;
        if c.read_model()? != image {
            c.upload(&image, false, |_| {})
                .with_context(|| format!("putting axis {}'s model back", axis_name(i as u8)))?;
        }
    }
    Ok(())
}

/// Keeps `x`, the first axis's tuned model, in the board's flash too.
fn store_first(c: &mut Client, x: &FirmwareModel) -> Result<()> {
    c.on_axis(0)?;
    let image = x.image().map_err(anyhow::Error::msg)?;
    c.upload(&image, true, |_| {})
        .context("storing x's tuned model in flash")?;
    Ok(())
}

/// Writes the file of several axes `file` to `out` (atomically).
pub fn write(file: &AxesModel, out: &std::path::Path) -> Result<()> {
    let text = file.to_toml().map_err(anyhow::Error::msg)?;
    crate::output::write_atomic(out, text.as_bytes())
}

/// What autotune of every axis prints: each axis's table, then the
/// coupling's.
pub fn table(a: &AxesAutotune) -> String {
    let mut out = String::new();
    for (i, t) in a.axes.iter().enumerate() {
        out.push_str(&format!("axis {}:\n", axis_name(i as u8)));
        out.push_str(&autotune::table(t));
    }
    out.push_str(&decoupling::table(&a.coupling));
    out
}
