//! Writes the seed corpus (`corpus/<target>/`) from the project's real inputs:
//! the first lines of the datasets in `tests-host/data`, the model files
//! (`firmware/model/stage-a.toml`, thinned to a few KB; the host models that
//! `fpi demo` writes to `tests-host/out/demo/models`, when they are there), the
//! factory model image, and link sessions encoded with the firmware's own framing.
//!
//! `cargo run --example seeds` (from `tests-host/fuzz`). Seeds are named after
//! what they hold; running it again rewrites the same files. Fuzzing adds its
//! finds under other names (hashes); `cargo fuzz cmin` minimises the lot.

use std::io::Write;
use std::path::{Path, PathBuf};

use fpi_firmware::link::frame;
use fpi_firmware::link::protocol::{BenchOrder, Command, Header, MAX_FRAME, VERSION};
use fpi_firmware::board::factory_model::MODEL_IMAGE;
use fpi_firmware::control::reference::wave::Shape;
use fpi_fuzz::image::EDIT;
use fpi_host::data::{dataset, read_bytes};
use piezo_sim::file::{FirmwareModel, TableSection};

fn corpus(target: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("corpus")
        .join(target);
    std::fs::create_dir_all(&dir).expect("corpus folder");
    dir
}

fn seed(target: &str, name: &str, bytes: &[u8]) {
    let path = corpus(target).join(name);
    std::fs::write(&path, bytes).expect("seed written");
    println!("{:>6} B  {}", bytes.len(), path.display());
}

/// The header and the first `rows` lines of a dataset.
fn head(relative: &str, rows: usize) -> String {
    let bytes = read_bytes(&dataset(relative)).expect("dataset readable");
    let text = String::from_utf8(bytes).expect("UTF-8 dataset");
    text.lines()
        .take(rows + 1)
        .map(|l| format!("{l}\n"))
        .collect()
}

/// Columns `keep` (0-based) of a comma-separated text.
fn cut(text: &str, keep: &[usize]) -> String {
    text.lines()
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            keep.iter().map(|&k| f[k]).collect::<Vec<_>>().join(",") + "\n"
        })
        .collect()
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    gz.write_all(bytes).expect("gzip");
    gz.finish().expect("gzip")
}

fn csv() {
    // Selector byte: see `fpi_fuzz::csv` (0 rig, 1 stage, 2 drive, 3 target,
    // 4 FEM, 5 micromanipulator, 6 points; 0x80: gzip).
    let with = |sel: u8, text: &[u8]| [&[sel][..], text].concat();
    let rig = head("pea-rig/preload_050N_sine_05Hz.csv", 20);
    seed("csv", "rig", &with(0, rig.as_bytes()));
    seed(
        "csv",
        "rig-minor",
        &with(
            0,
            head("pea-rig/preload_125N_minor_05Hz.csv", 12).as_bytes(),
        ),
    );
    let stage = head("stage-a/sine_15Hz.csv", 20);
    seed("csv", "stage", &with(1, stage.as_bytes()));
    seed(
        "csv",
        "stage-5-columns",
        &with(1, head("stage-a/chirp_large_060V.csv", 12).as_bytes()),
    );
    seed("csv", "stage-gz", &with(0x80 | 1, &gzip(stage.as_bytes())));
    seed("csv", "drive", &with(2, cut(&stage, &[0, 1]).as_bytes()));
    seed("csv", "target", &with(3, cut(&stage, &[0, 3]).as_bytes()));
    let fem = head("stage-a/fem.csv", 100);
    seed("csv", "fem", &with(4, fem.as_bytes()));
    let thin: String = fem
        .lines()
        .enumerate()
        .filter(|(i, _)| *i == 0 || i % 8 == 1)
        .map(|(_, l)| format!("{l}\n"))
        .collect();
    seed("csv", "fem-thin", &with(4, thin.as_bytes()));
    let mm = head("real/micromanipulator/Model_Vi_Do.dat", 20);
    seed("csv", "micromanipulator", &with(5, mm.as_bytes()));
    let points: String = std::iter::once("x_ref_um".to_string())
        .chain(cut(&stage, &[3]).lines().skip(1).map(str::to_string))
        .map(|l| l + "\n")
        .collect();
    seed("csv", "points", &with(6, points.as_bytes()));
    // What the readers refuse (each a different check).
    seed(
        "csv",
        "bad-header-only",
        &with(1, b"t_s,voltage_V,force_N,x_fhps_um\n"),
    );
    seed(
        "csv",
        "bad-duplicate-column",
        &with(2, b"t_s,voltage_V,t_s\n0,1,2\n"),
    );
    seed("csv", "bad-nan", &with(3, b"t_s,x_fhps_um\n0,1\n0.1,NaN\n"));
    seed(
        "csv",
        "bad-time",
        &with(
            0,
            b"t_s,voltage_V,force_N,displacement_um\n0,0,50,0\n0,0,50,0\n",
        ),
    );
    seed(
        "csv",
        "bad-fem-range",
        &with(4, b"x_pea_um,preload_N,x_fhps_um\n0,60,0\n1,1e9,1\n"),
    );
    seed(
        "csv",
        "bad-fem-monotone",
        &with(4, b"x_pea_um,preload_N,x_fhps_um\n0,60,0\n1,61,1\n2,62,1\n"),
    );
    seed(
        "csv",
        "bad-fields",
        &with(1, b"t_s,voltage_V,force_N,x_fhps_um\n0,0,60\n"),
    );
}

fn host_models() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../out/demo/models");
    let Ok(entries) = std::fs::read_dir(&dir) else {
        eprintln!(
            "note: {} is missing (run `fpi demo` to write it): no host model seeds",
            dir.display()
        );
        return;
    };
    let mut files: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
    files.sort();
    for f in files
        .iter()
        .filter(|f| f.extension().is_some_and(|e| e == "toml"))
    {
        let name = f.file_stem().and_then(|s| s.to_str()).unwrap_or("model");
        seed(
            "toml_host",
            name,
            &std::fs::read(f).expect("model readable"),
        );
    }
}

/// Every `2^k`-th knot of `t`, `k` as large as the core's table format allows
/// (`step_log2 ≤ 0`, neighbouring values less than 0.5 apart), values rounded to
/// 6 significant digits: the same shape in a few hundred bytes.
fn thin(t: &mut TableSection) {
    loop {
        let halved: Vec<f64> = t.values.iter().step_by(2).copied().collect();
        let fine = halved.windows(2).all(|w| (w[1] - w[0]).abs() < 0.4);
        if t.values.len() < 5
            || t.step_log2 >= 0
            || !(t.values.len() - 1).is_multiple_of(2)
            || !fine
        {
            break;
        }
        t.values = halved;
        t.step_log2 += 1;
    }
    for v in &mut t.values {
        *v = format!("{:.5e}", *v).parse().expect("a number");
    }
}

fn firmware_models() -> Vec<(String, Vec<u8>)> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../firmware/model/stage-a.toml");
    let text = std::fs::read_to_string(&path).expect("firmware model readable");
    let full = FirmwareModel::parse(&text, "stage-a.toml").expect("the firmware model parses");
    let mut small = full.clone();
    small.provenance.notes = String::new();
    for t in [
        &mut small.tables.f_f,
        &mut small.tables.f_k,
        &mut small.tables.f_k_inv,
    ] {
        thin(t);
    }
    for m in [&mut small.dead_zone, &mut small.saturation]
        .into_iter()
        .flatten()
    {
        thin(&mut m.forward);
        thin(&mut m.inverse);
    }
    let mut plain = small.clone();
    plain.dead_zone = None;
    plain.saturation = None;
    plain.creep.clear();
    let mut predicted = plain.clone();
    predicted.controller.force_source = "predicted".into();
    let mut images = Vec::new();
    for (name, m) in [
        ("stage-a-thin", &small),
        ("stage-a-plain", &plain),
        ("stage-a-predicted", &predicted),
    ] {
        match m.image() {
            Ok(img) => {
                let toml = m.to_toml().expect("model serialises");
                seed("toml_firmware", name, toml.as_bytes());
                images.push((name.to_string(), img));
            }
            Err(e) => eprintln!("note: {name} does not check ({e}): not a seed"),
        }
    }
    images
}

fn images(thinned: &[(String, Vec<u8>)]) {
    seed("model_image", "factory", MODEL_IMAGE);
    for (name, img) in thinned {
        seed("model_image", name, img);
    }
    // Edit scripts (records of `EDIT` bytes: op, offset u16 LE, 4 value bytes).
    let rec = |op: u8, off: u16, v: [u8; 4]| {
        let o = off.to_le_bytes();
        [op, o[0], o[1], v[0], v[1], v[2], v[3]]
    };
    let scripts: Vec<(&str, Vec<[u8; EDIT]>)> = vec![
        ("unchanged", vec![]),
        ("version", vec![rec(0, 4, [2, 0, 0, 0])]),
        ("count", vec![rec(3, 5, [0xff, 0, 0, 0])]),
        ("flip-body", vec![rec(2, 40, [0x80, 0, 0, 0])]),
        ("truncate", vec![rec(4, 200, [0; 4])]),
        ("insert", vec![rec(5, 24, [1, 2, 3, 4])]),
        ("remove", vec![rec(6, 24, [0; 4])]),
        (
            "stale-crc",
            vec![rec(2, 100, [1, 0, 0, 0]), rec(7, 0, [2, 0, 0, 0])],
        ),
        ("nan-like", vec![rec(3, 8, [0xff, 0xff, 0xff, 0x7f])]),
    ];
    for (name, s) in scripts {
        seed("model_image_edit", name, &s.concat());
    }
}

/// A request frame (delimiter first, as a host resynchronising).
fn request(seq: u16, cmd: &Command<'_>) -> Vec<u8> {
    let (mut scratch, mut out) = (vec![0; MAX_FRAME], vec![0; MAX_FRAME]);
    let h = Header {
        version: VERSION,
        seq,
    };
    let n = frame::encode(&h, cmd, &mut scratch, &mut out).expect("request encodes");
    [&[0u8][..], &out[..n]].concat()
}

/// The postcard bytes of a request (what `link_frames`' op 1 frames).
fn payload(seq: u16, cmd: &Command<'_>) -> Vec<u8> {
    let mut f = request(seq, cmd);
    f.pop();
    let mut raw = fpi_fuzz::link::uncobs(&f[1..]).expect("our own frame");
    raw.truncate(raw.len() - 4);
    raw
}

fn sessions() -> Vec<(&'static str, Vec<Command<'static>>)> {
    let mv = |um: i32| Command::Move {
        axis: 0,
        target: um << 16,
        speed: 200 << 16,
    };
    let mut pts = heapless::Vec::new();
    for k in 0..16 {
        let _ = pts.push((k * 2) << 16);
    }
    vec![
        (
            "hello",
            vec![
                Command::Hello,
                Command::Status { axis: 0 },
                Command::Ping,
                Command::Counters,
            ],
        ),
        (
            "move",
            vec![
                mv(10),
                Command::Status { axis: 0 },
                Command::Hold { axis: 0 },
                Command::Safe,
            ],
        ),
        (
            "wave",
            vec![
                Command::Wave {
                    axis: 0,
                    shape: Shape::Sine,
                    offset: 20 << 16,
                    amplitude: 5 << 16,
                    freq_mhz: 10_000,
                    cycles: 2,
                },
                Command::Record {
                    axis: 0,
                    decimation: 4,
                    signals: 0xff,
                },
                Command::ReadRecord { max: 32 },
                Command::RecordStop,
            ],
        ),
        (
            "stream",
            vec![
                Command::StreamClear { axis: 0 },
                Command::Points {
                    axis: 0,
                    first: 0,
                    points: pts,
                },
                Command::Stream {
                    axis: 0,
                    interval: 2,
                },
                Command::StreamEnd { axis: 0 },
            ],
        ),
        (
            "analog",
            vec![
                Command::Bench(BenchOrder::Analog(2048)),
                Command::Analog { axis: 0 },
                Command::Status { axis: 0 },
            ],
        ),
        (
            "faults",
            vec![
                Command::Supervise { timeout_ms: 5 },
                mv(15),
                Command::Bench(BenchOrder::SensorOpen(true)),
                Command::Status { axis: 0 },
                Command::Bench(BenchOrder::SensorOpen(false)),
                Command::ClearFault,
            ],
        ),
        (
            "bench",
            vec![
                Command::Bench(BenchOrder::SensorStuck(true)),
                Command::Bench(BenchOrder::SensorOffset(3 << 16)),
                Command::Bench(BenchOrder::Stall(3)),
                Command::Bench(BenchOrder::DamageStored),
                Command::Drive {
                    axis: 0,
                    compensated: false,
                },
                mv(5),
            ],
        ),
        (
            "model",
            vec![
                Command::ModelInfo { axis: 0 },
                Command::Safe,
                Command::ModelBegin { len: 16, crc: 0 },
                Command::ModelChunk {
                    offset: 0,
                    data: &[1, 2, 3, 4],
                },
                Command::ModelCommit {
                    axis: 0,
                    store: false,
                },
                Command::ModelFactory { axis: 0 },
                Command::Reset,
            ],
        ),
    ]
}

fn link() {
    for (name, cmds) in sessions() {
        let line: Vec<u8> = cmds
            .iter()
            .enumerate()
            .flat_map(|(k, c)| request(k as u16 + 1, c))
            .collect();
        seed("link_bytes", name, &line);
        // The same session as `link_frames` ops: each request framed by the
        // harness (op 1), with idle ticks (op 2) between.
        let mut ops = Vec::new();
        for (k, c) in cmds.iter().enumerate() {
            let p = payload(k as u16 + 1, c);
            ops.push(1);
            ops.extend_from_slice(&(p.len() as u16).to_le_bytes());
            ops.extend_from_slice(&p);
            ops.extend_from_slice(&[2, 200, 0]);
        }
        seed("link_frames", name, &ops);
    }
    // Garbage and broken frames on the line.
    seed(
        "link_bytes",
        "garbage",
        &[0, 1, 2, 3, 0, 0xff, 0xff, 0, 5, 1, 1, 1, 0],
    );
    let mut bad_crc = request(9, &Command::Status { axis: 0 });
    let n = bad_crc.len();
    bad_crc[n - 2] ^= 0x55;
    seed("link_bytes", "bad-crc", &bad_crc);
    let (mut scratch, mut out) = (vec![0; MAX_FRAME], vec![0; MAX_FRAME]);
    let old = Header {
        version: VERSION.wrapping_sub(1),
        seq: 3,
    };
    let n = frame::encode(&old, &Command::Hello, &mut scratch, &mut out).expect("encodes");
    seed("link_bytes", "old-version", &out[..n]);
    seed("link_bytes", "overlong", &vec![7u8; MAX_FRAME + 8]);
    // Uploads (op 3 | 4: store in flash) of the factory image, edited.
    let status = payload(50, &Command::Status { axis: 0 });
    let mut upload = vec![1, status.len() as u8, 0];
    upload.extend_from_slice(&status);
    let safe = payload(51, &Command::Safe);
    upload.extend([1, safe.len() as u8, 0]);
    upload.extend_from_slice(&safe);
    upload.extend([2, 0xff, 0x03]); // 1023 idle ticks: parked
    upload.extend([3 | 4, 0]); // the factory image, unedited, stored
    upload.extend([3, 7, 2, 40, 0, 0x80, 0, 0, 0]); // one bit flipped, CRC fixed up, not stored
    let info = payload(52, &Command::ModelInfo { axis: 0 });
    upload.extend([1, info.len() as u8, 0]);
    upload.extend_from_slice(&info);
    seed("link_frames", "upload", &upload);
}

fn main() {
    csv();
    host_models();
    let thinned = firmware_models();
    images(&thinned);
    link();
}
