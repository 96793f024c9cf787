//! Generates the firmware's flash-resident model from the checked-in model file,
//! the reference generator's cosine table, and puts `memory.x` (the top level of
//! the project) on the linker's path.
//!
//! * `$OUT_DIR/model.rs` — the FPI parameters, the FEM tables and the loop settings
//!   of `firmware/model/stage-a.toml` (or of the file named by `PIEZO_FPI_MODEL`,
//!   relative to the project's top level), read, quantised and validated by the
//!   same code the host tools use (`piezo_sim::file`, the core's validator). A
//!   malformed file fails the build with a message naming the file, the key and
//!   the value.
//! * `$OUT_DIR/cosine.rs` — the reference generator's cosine table.

use std::env;
use std::fmt::Write as _;
use std::fs;
use std::path::{Path, PathBuf};

use piezo_fpi::model::{ModelSpec, TableSpec};
use piezo_sim::file::FirmwareModel;

const DEFAULT_MODEL: &str = "firmware/model/stage-a.toml";

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=../memory.x");
    println!("cargo:rerun-if-env-changed=PIEZO_FPI_MODEL");
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    let manifest = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets it"));
    let root = manifest
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or(manifest.clone());

    // The linker finds memory.x (cortex-m-rt's link.x includes it) in OUT_DIR.
    let memory = fs::read_to_string(root.join("memory.x")).expect("read memory.x");
    fs::write(out.join("memory.x"), memory_for_build(&memory)).expect("write memory.x");
    println!("cargo:rustc-link-search={}", out.display());

    let model_path = match env::var("PIEZO_FPI_MODEL") {
        Ok(p) if !p.is_empty() => root.join(p),
        _ => root.join(DEFAULT_MODEL),
    };
    println!("cargo:rerun-if-changed={}", model_path.display());
    let code = match generate_model(&model_path) {
        Ok(code) => code,
        Err(msg) => {
            // One clear line, then stop the build.
            eprintln!("error: firmware model: {msg}");
            println!("cargo:warning=firmware model: {msg}");
            std::process::exit(1);
        }
    };
    fs::write(out.join("model.rs"), code.0).expect("write model.rs");
    fs::write(out.join("model.image"), code.1).expect("write model.image");
    fs::write(out.join("cosine.rs"), cosine_table()).expect("write cosine.rs");
}

/// The board's memory map; for the emulated board (feature `qemu`) with the SRAM
/// QEMU's netduinoplus2 has beyond the chip's 128 KiB (192 KiB in all): the
/// emulated board keeps its model "flash" in RAM, which the real board does not
/// need. The board build's figures stay those of the real chip.
fn memory_for_build(memory: &str) -> String {
    println!("cargo:rerun-if-env-changed=CARGO_FEATURE_QEMU");
    if env::var_os("CARGO_FEATURE_QEMU").is_some() {
        let emulated = memory.replace("LENGTH = 128K", "LENGTH = 192K");
        assert_ne!(emulated, memory, "memory.x: RAM LENGTH = 128K expected");
        format!("/* Emulated board: 192 KiB SRAM (QEMU netduinoplus2). */\n{emulated}")
    } else {
        memory.to_string()
    }
}

/// Reads, quantises and validates the model file; the Rust code of its model and
/// its image (the board's factory default).
fn generate_model(path: &Path) -> Result<(String, Vec<u8>), String> {
    let shown = path.display().to_string();
    let text = fs::read_to_string(path).map_err(|e| format!("{shown}: cannot read: {e}"))?;
    let file = FirmwareModel::parse(&text, &shown)?;
    let (quantized, shape) = file.check().map_err(|e| format!("{shown}: {e}"))?;
    let q = quantized.spec();
    let mut s = String::new();
    header(&mut s, &shown, &q, shape.operators);
    pi(&mut s, &q);
    types(&mut s, &q);
    fpi(&mut s, &q);
    for (name, map) in [("DEAD_ZONE", &q.dead_zone), ("SATURATION", &q.saturation)] {
        if let Some(m) = map {
            table(&mut s, &format!("{name}_FORWARD"), "The map.", &m.forward);
            table(
                &mut s,
                &format!("{name}_INVERSE"),
                "Its inverse.",
                &m.inverse,
            );
        }
    }
    table(
        &mut s,
        "F_F",
        "Preload `f_F`: stack extension (µm) → force (N).",
        &q.f_f,
    );
    table(
        &mut s,
        "F_K",
        "Kinematics `f_K`: stack extension (µm) → stage output (µm).",
        &q.f_k,
    );
    table(
        &mut s,
        "F_K_INV",
        "Inverse kinematics `f_K⁻¹`: stage output (µm) → stack extension (µm).",
        &q.f_k_inv,
    );
    controller(&mut s, &q, file.controller.slew_v_per_ms);
    let mut image = vec![0; piezo_fpi::model::image::encoded_len(&q)];
    piezo_fpi::model::image::encode(&q, &mut image).map_err(|e| format!("{shown}: {e}"))?;
    Ok((s, image))
}

fn header(w: &mut String, shown: &str, q: &ModelSpec<'_>, operators: usize) {
    let _ = writeln!(w, "// Generated by build.rs from {shown}. Do not edit.");
    let _ = writeln!(w, "/// Path of the model file this build embeds.");
    let _ = writeln!(w, "pub const MODEL_FILE: &str = {shown:?};");
    let _ = writeln!(
        w,
        "/// Text of the embedded model file (host tests parse it; unused code on the board)."
    );
    let _ = writeln!(w, "pub const MODEL_TOML: &str = include_str!({shown:?});");
    let _ = writeln!(w, "/// Number of play operators of the embedded model.");
    let _ = writeln!(w, "pub const OPERATORS: usize = {operators};");
    let _ = writeln!(w, "/// Creep terms of the embedded model.");
    let _ = writeln!(w, "pub const CREEP_TERMS: usize = {};", q.creep.len());
    let _ = writeln!(w, "/// Control ISR rate, Hz.");
    let _ = writeln!(w, "pub const CONTROL_RATE_HZ: u32 = {};", q.rate_hz);
}

/// `[Type::from_bits(b), …]`, four to a line.
fn list(items: impl IntoIterator<Item = i32>, ty: &str) -> String {
    let mut l = String::from("[");
    for (i, b) in items.into_iter().enumerate() {
        if i % 4 == 0 {
            l.push_str("\n    ");
        }
        let _ = write!(l, "{ty}::from_bits({b}), ");
    }
    l.push_str("\n]");
    l
}

fn pi(w: &mut String, q: &ModelSpec<'_>) {
    let _ = writeln!(
        w,
        "/// The forward PI model (validated by the compiler).\n\
         pub const PI: PiModel<OPERATORS> = match PiModel::new(\n    \
         UmPerVolt::from_bits({}),\n    {},\n    {},\n    Volts::from_bits({}),\n) {{\n    \
         Ok(m) => m,\n    Err(e) => panic!(\"{{}}\", e.message()),\n}};",
        q.w0.to_bits(),
        list(q.operators.iter().map(|o| o.threshold.to_bits()), "Volts"),
        list(q.operators.iter().map(|o| o.weight.to_bits()), "UmPerVolt"),
        q.input_max.to_bits(),
    );
}

/// The model's structure as types: a `Map` or `Identity` for `g` and `h`.
fn types(w: &mut String, q: &ModelSpec<'_>) {
    let shape = |m: &Option<_>| {
        if m.is_some() {
            "Map<'static>"
        } else {
            "Identity"
        }
    };
    let _ = writeln!(
        w,
        "/// The embedded model's dead zone `g`: a soft one (`Map`) or the hard one (`Identity`).\n\
         pub type DeadZone = {};\n\
         /// The embedded model's output saturation `h`: a `Map`, or none (`Identity`).\n\
         pub type Saturation = {};\n\
         /// The embedded model's type.\n\
         pub type Model = Fpi<'static, OPERATORS, CREEP_TERMS, DeadZone, Saturation>;\n\
         /// The embedded controller's type.\n\
         pub type Controller = ControllerConfig<'static, OPERATORS, CREEP_TERMS, DeadZone, Saturation>;",
        shape(&q.dead_zone),
        shape(&q.saturation),
    );
}

fn fpi(w: &mut String, q: &ModelSpec<'_>) {
    let map = |name: &str, m: &Option<_>| match m {
        Some(_) => format!("Map {{ forward: {name}_FORWARD, inverse: {name}_INVERSE }}"),
        None => "Identity".into(),
    };
    let mut creep = String::from("[");
    for c in q.creep {
        let _ = write!(
            creep,
            "\n    match Creep::new(CreepRate::from_bits({}), UmPerVolt::from_bits({})) {{ Ok(c) => c, Err(e) => panic!(\"{{}}\", e.message()) }},",
            c.rate.to_bits(),
            c.gain.to_bits()
        );
    }
    creep.push_str("\n]");
    let c = &q.coupling;
    let _ = writeln!(
        w,
        "/// The FPI model: PI, the closed-form inverse (computed by the compiler), coupling,\n\
         /// dead zone, saturation and creep.\n\
         pub const FPI: Model = match Fpi::new(\n    PI,\n    Coupling {{\n        \
         offset: Volts::from_bits({}),\n        k_f: VoltsPerNewton::from_bits({}),\n        \
         k_q: VoltsPerNewton2::from_bits({}),\n        force_q: Newtons::from_bits({}),\n        \
         compliance: UmPerNewton::from_bits({}),\n        force_ref: Newtons::from_bits({}),\n    }},\n    \
         {},\n    {},\n    {},\n) {{\n    Ok(m) => m,\n    Err(e) => panic!(\"{{}}\", e.message()),\n}};",
        c.offset.to_bits(),
        c.k_f.to_bits(),
        c.k_q.to_bits(),
        c.force_q.to_bits(),
        c.compliance.to_bits(),
        c.force_ref.to_bits(),
        map("DEAD_ZONE", &q.dead_zone),
        map("SATURATION", &q.saturation),
        creep,
    );
}

fn table(w: &mut String, name: &str, doc: &str, t: &TableSpec<'_>) {
    let _ = writeln!(
        w,
        "static {name}_SEGMENTS: [Segment; {}] = [",
        t.segments.len()
    );
    for s in t.segments {
        let _ = writeln!(
            w,
            "    Segment::from_bits({}, {}),",
            s.start().to_bits(),
            s.rise().to_bits()
        );
    }
    let _ = writeln!(w, "];");
    let _ = writeln!(
        w,
        "/// {doc}\npub const {name}: Table<'static> = match Table::new(I16F16::from_bits({}), {}, &{name}_SEGMENTS) {{\n    \
         Ok(t) => t,\n    Err(e) => panic!(\"{{}}\", e.message()),\n}};",
        t.x0.to_bits(),
        t.shift
    );
}

fn controller(w: &mut String, q: &ModelSpec<'_>, slew_v_per_ms: f64) {
    let _ = writeln!(
        w,
        "/// Actuator range and slew ({slew_v_per_ms} V/ms at {} Hz).\n\
         pub const LIMITS: OutputLimits = match OutputLimits::new(\n    \
         Volts::from_bits({}), Volts::from_bits({}), Volts::from_bits({})) {{\n    \
         Ok(l) => l,\n    Err(e) => panic!(\"{{}}\", e.message()),\n}};",
        q.rate_hz,
        q.u_min.to_bits(),
        q.u_max.to_bits(),
        q.max_step.to_bits(),
    );
    let _ = writeln!(
        w,
        "/// The control loop's configuration, in flash.\n\
         pub static CONTROLLER: Controller =\n    \
         match ControllerConfig::new(ControllerParts {{\n        \
         fpi: FPI,\n        f_f: F_F,\n        f_k: F_K,\n        f_k_inv: F_K_INV,\n        \
         limits: LIMITS,\n        supervision: Supervision {{\n            \
         reference: Interval {{ lo: Micrometres::from_bits({}), hi: Micrometres::from_bits({}) }},\n            \
         force: Interval {{ lo: Newtons::from_bits({}), hi: Newtons::from_bits({}) }},\n            \
         force_tolerance: Newtons::from_bits({}),\n            \
         safe_voltage: Volts::from_bits({}),\n            \
         force_source: ForceSource::{:?},\n        }},\n    }}) {{\n        \
         Ok(c) => c,\n        Err(e) => panic!(\"{{}}\", e.message()),\n    }};",
        q.supervision.reference.lo.to_bits(),
        q.supervision.reference.hi.to_bits(),
        q.supervision.force.lo.to_bits(),
        q.supervision.force.hi.to_bits(),
        q.supervision.force_tolerance.to_bits(),
        q.supervision.safe_voltage.to_bits(),
        q.supervision.force_source,
    );
}

/// cos(2π k/256), k = 0..=256, as I2F30 raw values.
fn cosine_table() -> String {
    let mut s = String::from(
        "// Generated by build.rs. cos(2*pi*k/256), k = 0..=256, I2F30.\nstatic COSINE: [i32; 257] = [\n",
    );
    for k in 0..=256 {
        let c = (k as f64 / 256.0 * std::f64::consts::TAU).cos();
        let _ = write!(s, "{},", (c * (1u64 << 30) as f64).round() as i32);
        if k % 8 == 7 {
            s.push('\n');
        }
    }
    s.push_str("\n];\n");
    s
}
