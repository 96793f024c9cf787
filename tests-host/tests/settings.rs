//! The board's runtime settings by key path (`fpi_protocol::Settings`), on the
//! in-process board (`virtual`, the firmware built for this host): every
//! setting reads back as the board's state; a set is carried out as the named
//! command that makes it, with that command's checks and refusals; a key the
//! board does not have, a value not of the setting's type and a setting the
//! running model lacks are refused naming the key (and the value); and
//! `fpi board get|set` print them.

use fpi_host::board::client::{refusal, Client};
use fpi_host::board::settings::{path, read_all};
use fpi_host::method::tune::{tune_measured, with_tuning, TuneOptions};
use fpi_protocol::{Command, LoopMode, Reply};
use piezo_fpi::damping::DynamicsSpec;
use piezo_fpi::q::{CreepRate, NewtonsPerUm};
use piezo_sim::file::FirmwareModel;

mod common;
use common::{ok, refused};

/// The factory model with loops designed for stage A as autotune fits it
/// (`[dynamics]`, `[damping]`, `[feedback]`, `[shaping]`).
fn tuned() -> FirmwareModel {
    let d = DynamicsSpec {
        mode_mhz: 850_000,
        damping: CreepRate::from_num(0.03),
        lag_mhz: 1_900_000,
        force_gain: NewtonsPerUm::from_num(6.3),
    };
    let fw = fpi_tests::factory_model();
    let o = TuneOptions::default();
    with_tuning(&fw, &tune_measured(&fw, d, &o).unwrap(), &o).unwrap()
}

/// The board's refusal of `cmd`, its reason.
fn refusal_of(c: &mut Client, cmd: &Command<'_>) -> String {
    let e = c.ack(cmd).unwrap_err();
    refusal(&e).expect("a refusal").reason.clone()
}

fn get(c: &mut Client, key: &str) -> String {
    c.setting(&path(key).unwrap()).unwrap()
}

#[test]
fn every_setting_reads_back_as_the_board_s_state() {
    let mut c = Client::open("virtual").unwrap();
    let all = read_all(&mut c).unwrap();
    let shown: Vec<(&str, Option<&str>)> = all
        .iter()
        .map(|(p, v)| (p.as_str(), v.as_deref()))
        .collect();
    // The factory model has no damping and no shaping: those are absent.
    assert_eq!(
        shown,
        [
            ("/stage/0/loop_mode", Some("\"open\"")),
            ("/stage/0/damping", None),
            ("/stage/0/shaping", None),
            ("/stage/0/compensated", Some("true")),
            ("/stage/0/trigger/mode", Some("\"off\"")),
            ("/stage/0/trigger/step_nm", Some("1000")),
            ("/stage/0/trigger/band_nm", Some("100")),
            ("/stage/0/trigger/low_nm", Some("0")),
            ("/stage/0/trigger/high_nm", Some("0")),
            ("/stage/0/trigger/pulse_ticks", Some("1")),
            ("/stage/0/trigger_in", Some("\"off\"")),
            ("/supervise_ms", Some("0")),
        ]
    );
    // Set by key, seen in the status; set by the named command, seen by key.
    c.set_setting("/stage/0/compensated", "false").unwrap();
    assert!(!c.status().unwrap().compensated);
    c.ack(&Command::Drive {
        axis: 0,
        compensated: true,
    })
    .unwrap();
    assert_eq!(get(&mut c, "stage.0.compensated"), "true");
    c.set_setting("/supervise_ms", "250").unwrap();
    let rate = c.rate_hz();
    assert_eq!(
        c.status().unwrap().supervision[0],
        (250.0 * rate / 1000.0) as u32
    );
    assert_eq!(get(&mut c, "supervise_ms"), "250");
    c.set_setting("/supervise_ms", "0").unwrap();
    // Nothing changes: acknowledged, nothing done.
    c.set_setting("/stage/0/loop_mode", "\"open\"").unwrap();
}

#[test]
fn a_set_passes_its_named_command_s_checks() {
    let mut c = Client::open("virtual").unwrap();
    // The factory model has no [feedback]: closing is refused either way, alike.
    let named = refusal_of(
        &mut c,
        &Command::Loop {
            axis: 0,
            mode: LoopMode::Closed,
        },
    );
    let by_key = refusal_of(
        &mut c,
        &Command::SettingSet {
            path: b"/stage/0/loop_mode",
            value: b"\"closed\"",
        },
    );
    assert_eq!(by_key, named);
    assert_eq!(get(&mut c, "stage/0/loop_mode"), "\"open\"");
    // A tuned model: damping and shaping are there, and switch by key.
    c.park().unwrap();
    c.upload(&tuned().image().unwrap(), false, |_| {}).unwrap();
    assert_eq!(get(&mut c, "stage/0/damping"), "true");
    assert_eq!(get(&mut c, "stage/0/shaping"), "true");
    c.set_setting("/stage/0/damping", "false").unwrap();
    assert_eq!(c.status().unwrap().damping, Some(false));
    c.set_setting("/stage/0/shaping", "false").unwrap();
    assert_eq!(c.status().unwrap().shaping, Some(false));
    // Its gains are tuned with the damping: the loop does not close without it
    // (the `Loop` command's check), and does with it.
    let e = c
        .set_setting("/stage/0/loop_mode", "\"closed\"")
        .unwrap_err();
    assert!(
        refusal(&e)
            .unwrap()
            .reason
            .starts_with("unstable on the 850.000 Hz mode without damping"),
        "{e:#}"
    );
    c.set_setting("/stage/0/damping", "true").unwrap();
    c.set_setting("/stage/0/loop_mode", "\"closed\"").unwrap();
    assert_eq!(c.status().unwrap().loop_mode, LoopMode::Closed);
    // Closed on the mode: the damping stays on (the `Damping` command's check).
    let e = c.set_setting("/stage/0/damping", "false").unwrap_err();
    assert!(format!("{e:#}").contains("without damping"), "{e:#}");
    assert_eq!(get(&mut c, "stage/0/damping"), "true");
    c.park().unwrap();
}

/// A key path, the value set (`None`: a get) and the board's reason.
type Case = (&'static [u8], Option<&'static [u8]>, &'static str);

#[test]
fn keys_values_and_absent_settings_are_refused_by_name() {
    let mut c = Client::open("virtual").unwrap();
    let cases: [Case; 6] = [
        (
            b"/stage/0/dampng",
            None,
            "no setting /stage/0/dampng: `fpi board get` lists them",
        ),
        (
            b"/stage/1/damping",
            None,
            "no setting /stage/1/damping: `fpi board get` lists them",
        ),
        (
            b"/stage/0",
            None,
            "/stage/0 holds settings, not a value: name one of them",
        ),
        (
            b"/stage/0/damping",
            None,
            "/stage/0/damping: the running model has no such section",
        ),
        (
            b"/stage/0/compensated",
            Some(b"\"yes\""),
            "/stage/0/compensated = \"yes\": not a value of this setting's type",
        ),
        (
            b"/stage/0/loop_mode",
            Some(b"\"shut\""),
            "/stage/0/loop_mode = \"shut\": not a value of this setting's type",
        ),
    ];
    for (path, value, said) in cases {
        let cmd = match value {
            Some(value) => Command::SettingSet { path, value },
            None => Command::SettingGet { path },
        };
        match c.request(&cmd).unwrap().1 {
            Reply::Refused { code, reason } => {
                assert_eq!(code, fpi_protocol::Refusal::Setting);
                assert_eq!(reason.as_str(), said);
            }
            r => panic!("{cmd:?}: {r:?}"),
        }
    }
    // Nothing was changed by the refused sets.
    assert_eq!(get(&mut c, "stage/0/compensated"), "true");
    assert_eq!(get(&mut c, "stage/0/loop_mode"), "\"open\"");
}

#[test]
fn fpi_board_get_and_set_print_the_settings() {
    let out = ok(&["board", "--port", "virtual", "get"]);
    assert_eq!(
        out.lines().collect::<Vec<_>>(),
        [
            "stage/0/loop_mode           \"open\"",
            "stage/0/damping             (the running model has none)",
            "stage/0/shaping             (the running model has none)",
            "stage/0/compensated         true",
            "stage/0/trigger/mode        \"off\"",
            "stage/0/trigger/step_nm     1000",
            "stage/0/trigger/band_nm     100",
            "stage/0/trigger/low_nm      0",
            "stage/0/trigger/high_nm     0",
            "stage/0/trigger/pulse_ticks 1",
            "stage/0/trigger_in          \"off\"",
            "supervise_ms                0",
        ]
    );
    let out = ok(&[
        "board",
        "--port",
        "virtual",
        "set",
        "stage.0.compensated",
        "off",
    ]);
    assert!(
        out.starts_with("stage/0/compensated = false from tick "),
        "{out}"
    );
    refused(
        &["board", "--port", "virtual", "set", "stage/0/loop_mode", "closed"],
        &["the board refused set /stage/0/loop_mode = \"closed\": the running model has no [feedback] section"],
    );
    refused(
        &["board", "--port", "virtual", "get", "stage/0/lop"],
        &["no setting \"stage/0/lop\": the board's settings are stage/0/loop_mode, "],
    );
}
