//! Bad input files get errors that name the file, the line and the column.

use fpi_host::data::{read_fem, read_rig, read_stage};
use std::path::PathBuf;

fn write(name: &str, text: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("fpi-host-data-errors-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn message(r: Result<impl std::fmt::Debug, fpi_host::data::DataError>) -> String {
    r.expect_err("must fail").to_string()
}

#[test]
fn a_non_number_names_line_and_column() {
    let p = write(
        "bad_number.csv",
        "t_s,voltage_V,force_N,displacement_um\n0,0,60,0\n0.1,1.5,6O.1,0.01\n",
    );
    let m = message(read_rig(&p));
    assert!(
        m.ends_with("bad_number.csv:3: column force_N: \"6O.1\" is not a number"),
        "{m}"
    );
}

#[test]
fn nan_and_infinity_are_rejected() {
    let p = write(
        "nan.csv",
        "t_s,voltage_V,force_N,x_fhps_um\n0,0,60,0\n0.1,NaN,60,0.2\n",
    );
    let m = message(read_stage(&p));
    assert!(
        m.ends_with("nan.csv:3: column voltage_V: \"NaN\" is not a finite number"),
        "{m}"
    );
    let p = write(
        "inf.csv",
        "x_pea_um,preload_N,x_fhps_um\n0,61.8,0\n0.25,inf,1.4\n",
    );
    let m = message(read_fem(&p));
    assert!(
        m.ends_with("inf.csv:3: column preload_N: \"inf\" is not a finite number"),
        "{m}"
    );
}

#[test]
fn a_missing_column_is_named() {
    let p = write("missing.csv", "t_s,voltage_V,x_fhps_um\n0,0,0\n");
    let m = message(read_stage(&p));
    assert!(
        m.contains("missing.csv:1: column force_N: missing in the header"),
        "{m}"
    );
}

#[test]
fn a_short_row_is_located() {
    let p = write(
        "short.csv",
        "t_s,voltage_V,force_N,displacement_um\n0,0,60,0\n0.1,1\n",
    );
    let m = message(read_rig(&p));
    assert!(
        m.contains("short.csv:3: 2 fields where the header has 4"),
        "{m}"
    );
}

#[test]
fn fem_extension_must_increase_and_time_too() {
    let p = write(
        "fem_order.csv",
        "x_pea_um,preload_N,x_fhps_um\n0,61.8,0\n0.5,63,2.8\n0.25,62,1.4\n",
    );
    let m = message(read_fem(&p));
    assert!(
        m.ends_with("fem_order.csv:4: column x_pea_um: 0.25 does not increase (previous row 0.5)"),
        "{m}"
    );
    let p = write(
        "time.csv",
        "t_s,voltage_V,force_N,displacement_um\n0,0,60,0\n0,1,60,0\n",
    );
    let m = message(read_rig(&p));
    assert!(
        m.ends_with("time.csv:3: column t_s: 0 does not increase (previous row 0)"),
        "{m}"
    );
}

#[test]
fn an_absent_file_is_named() {
    let m = message(read_rig(std::path::Path::new("/nonexistent/run.csv")));
    assert!(m.starts_with("/nonexistent/run.csv: cannot open"), "{m}");
}

#[test]
fn extra_columns_are_ignored() {
    let p = write(
        "extra.csv",
        "t_s,voltage_V,force_N,x_fhps_um,current_mA\n0,0,60,0,0.1\n0.1,1,60,0.2,0.3\n",
    );
    let run = read_stage(&p).unwrap();
    assert_eq!(run.u, vec![0.0, 1.0]);
}

#[test]
fn a_duplicate_column_is_named_by_its_fields() {
    let p = write(
        "dup_header.csv",
        "t_s,voltage_V,force_N,x_fhps_um,force_N\n0,0,60,0,61\n0.1,1,60,0.2,61\n",
    );
    let m = message(read_stage(&p));
    assert!(
        m.ends_with(
            "dup_header.csv:1: column force_N: appears twice in the header (fields 3 and 5): \
             which one holds the data?"
        ),
        "{m}"
    );
}

#[test]
fn content_beyond_the_limits_is_refused_while_reading() {
    use fpi_host::data::{read_bytes, read_bytes_within, ReadLimits};
    use std::io::Write;
    let p = write("long.csv", &"0123456789".repeat(1000));
    let small = ReadLimits {
        max_bytes: 4096,
        ..ReadLimits::INPUT
    };
    let m = message(read_bytes_within(&p, small));
    assert!(
        m.starts_with(&format!("{}: more than 4096 bytes of content", p.display())),
        "{m}"
    );
    assert_eq!(read_bytes(&p).unwrap().len(), 10_000);

    // A gzip bomb: 200 MB of zeros in about 200 kB, refused after a few MB.
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    let zeros = vec![0u8; 1 << 20];
    for _ in 0..200 {
        gz.write_all(&zeros).unwrap();
    }
    let packed = gz.finish().unwrap();
    assert!(packed.len() < 1 << 20, "{}", packed.len());
    let dir = std::env::temp_dir().join(format!("fpi-host-data-errors-{}", std::process::id()));
    let bomb = dir.join("bomb.csv.gz");
    std::fs::write(&bomb, &packed).unwrap();
    let start = std::time::Instant::now();
    let m = message(read_bytes(&bomb));
    assert!(
        m.starts_with(&format!("{}: ", bomb.display()))
            && m.contains("a ratio above 100:1")
            && m.contains("a gzip bomb?"),
        "{m}"
    );
    assert!(start.elapsed().as_secs() < 5, "{:?}", start.elapsed());
    let m = message(read_stage(&bomb));
    assert!(m.contains("bomb.csv.gz") && m.contains("gzip bomb"), "{m}");
}

#[test]
fn fem_values_beyond_the_signal_range_are_refused_by_line() {
    use fpi_host::data::fem::FemMaps;
    let p = write(
        "fem_huge.csv",
        "x_pea_um,preload_N,x_fhps_um\n0,61.8,0\n0.5,63,2.8\n1e300,64,5.6\n",
    );
    let m = message(FemMaps::read(&p));
    assert!(
        m.contains("fem_huge.csv:4: column x_pea_um: 1e300 µm is outside ±4096 µm"),
        "{m}"
    );
    let p = write(
        "fem_preload.csv",
        "x_pea_um,preload_N,x_fhps_um\n0,61.8,0\n0.5,-1e9,2.8\n1,64,5.6\n",
    );
    let m = message(FemMaps::read(&p));
    assert!(
        m.contains("fem_preload.csv:3: column preload_N: -1e9 N is outside ±4096 N"),
        "{m}"
    );
}

/// Gzip-compresses `text` into `name` (two members when `split`), next to [`write`]'s files.
fn write_gz(name: &str, text: &str, split: bool) -> PathBuf {
    use std::io::Write;
    let p = write(name, "");
    let mut out = Vec::new();
    let parts: Vec<&str> = if split {
        let (a, b) = text.split_at(text.len() / 2);
        vec![a, b]
    } else {
        vec![text]
    };
    for part in parts {
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        gz.write_all(part.as_bytes()).unwrap();
        out.extend(gz.finish().unwrap());
    }
    std::fs::write(&p, out).unwrap();
    p
}

#[test]
fn a_gzip_file_reads_as_its_content_member_by_member() {
    let mut text = String::from("t_s,voltage_V,force_N,displacement_um\n");
    for k in 0..10_000 {
        text.push_str(&format!(
            "{},{},60,{}\n",
            k as f64 * 1e-3,
            k % 150,
            k as f64 * 1e-4
        ));
    }
    let plain = fpi_host::data::read_rig(&write("rows.csv", &text)).unwrap();
    assert_eq!(plain.t.len(), 10_000);
    for split in [false, true] {
        let gz = fpi_host::data::read_rig(&write_gz("rows.csv.gz", &text, split)).unwrap();
        assert_eq!(
            (&gz.t, &gz.u, &gz.f, &gz.x),
            (&plain.t, &plain.u, &plain.f, &plain.x)
        );
    }
}

#[test]
fn parse_csv_on_bytes_reads_and_refuses_as_the_file_readers_do() {
    use fpi_host::data::{parse_csv, RigRow};
    let columns = ["t_s", "voltage_V", "force_N", "displacement_um"];
    let text = "t_s,voltage_V,force_N,displacement_um\n0,0,60,0\n0.1,1.5,60.1,0.01\n";
    let name = std::path::Path::new("mem.csv");
    let rows: Vec<RigRow> = parse_csv(name, text.as_bytes(), &columns).unwrap();
    let rig = read_rig(&write("mem.csv", text)).unwrap();
    assert_eq!(rows.iter().map(|r| r.voltage_v).collect::<Vec<_>>(), rig.u);
    let bad: [&[u8]; 7] = [
        b"t_s,voltage_V,force_N,displacement_um\n0,0,60,0\n0.1,1.5,6O.1,0.01\n",
        b"t_s,voltage_V,force_N,displacement_um\n0,0,60,0\n0.1,1\n",
        b"t_s,voltage_V,force_N,displacement_um\n0,inf,60,0\n",
        b"t_s,voltage_V,force_N,force_N,displacement_um\n",
        b"t_s,voltage_V,displacement_um\n0,0,0\n",
        b"t_s,voltage_V,force_N,displacement_um\n",
        b"t_s,voltage_V,force_N,displacement_um\n0,0,60,0\n1,\xff,60,0\n",
    ];
    for bad in bad {
        let from_bytes = parse_csv::<RigRow>(name, bad, &columns).unwrap_err();
        let p = write("mem.csv", "");
        std::fs::write(&p, bad).unwrap();
        let mut from_file = read_rig(&p).unwrap_err();
        from_file.file = name.to_path_buf();
        assert_eq!(from_bytes, from_file, "{}", String::from_utf8_lossy(bad));
    }
    let m = message(parse_csv::<RigRow>(
        name,
        b"t_s,voltage_V,force_N,displacement_um\n",
        &columns,
    ));
    assert_eq!(m, "mem.csv: no data rows");
}

#[test]
fn limits_and_gzip_errors_surface_from_the_middle_of_a_csv() {
    use fpi_host::data::{for_each_record, open_within, ReadLimits, RigRow};
    let columns = ["t_s", "voltage_V", "force_N", "displacement_um"];
    let mut text = String::from("t_s,voltage_V,force_N,displacement_um\n");
    for k in 0..20_000 {
        text.push_str(&format!("{},1,60,0\n", k as f64 * 1e-3));
    }
    let p = write("limited.csv", &text);
    let small = ReadLimits {
        max_bytes: 100_000,
        ..ReadLimits::INPUT
    };
    let mut rows = 0;
    let e = for_each_record(
        &p,
        open_within(&p, small).unwrap(),
        &columns,
        |_: RigRow| rows += 1,
    )
    .unwrap_err();
    assert_eq!(
        e.to_string(),
        format!(
            "{}: more than 100000 bytes of content: refusing to read further (no dataset is that \
             large; a gzip bomb?)",
            p.display()
        )
    );
    assert!(rows > 0 && rows < 20_000, "{rows}");

    // Valid rows that expand 1000 times: refused as a bomb, not parsed to the end.
    let mut bomb = String::from("t_s,voltage_V,force_N,displacement_um\n");
    bomb.push_str(&"0,0,60,0\n".repeat(3 << 20));
    let p = write_gz("rows_bomb.csv.gz", &bomb, false);
    let e = read_rig(&p).unwrap_err();
    assert_eq!((e.file.as_path(), e.line), (p.as_path(), None));
    assert!(
        e.message.contains("a ratio above 100:1") && e.message.contains("a gzip bomb?"),
        "{e}"
    );

    // Not gzip, or cut short: named, as reading the whole file named them.
    let p = write(
        "not_gzip.csv.gz",
        "t_s,voltage_V,force_N,displacement_um\n0,0,60,0\n",
    );
    let m = message(read_rig(&p));
    assert!(
        m.starts_with(&format!("{}: cannot read: ", p.display())),
        "{m}"
    );
    let whole = std::fs::read(write_gz("cut.csv.gz", &text, false)).unwrap();
    let p = write("cut.csv.gz", "");
    std::fs::write(&p, &whole[..whole.len() / 2]).unwrap();
    let m = message(read_rig(&p));
    assert!(
        m.starts_with(&format!("{}: cannot read: ", p.display())),
        "{m}"
    );
    assert_eq!(m, message(fpi_host::data::read_bytes(&p)));
}
