"""The board from Python, on the in-process board and the emulated board: each
`fpi board` command as a method, the board's refusals, bad arguments, Ctrl-C
during record and stream, the link's loss."""

import _thread
import threading
import time

import numpy as np
import pytest

import piezo_fpi as pf

from conftest import ROOT, DATA

COLUMNS = ["t_s", "voltage_V", "force_N", "x_ref_um", "x_est_um", "status", "x_fhps_um", "x_sensor_um"]


def test_starts_parked_with_the_factory_model(board):
    s = board.status()
    assert s["state"] == "parked"
    assert s["fault"] is None
    assert s["amplifier_on"] is False
    assert s["model"]["origin"] == "Factory"
    # The factory model has no damping: no lead to learn.
    assert s["damping"] is None and s["lead_ratio"] is None and s["lead_applied"] is None
    lo, hi = s["model"]["stroke_um"]
    assert lo == 0.0 and 39 < hi < 41
    assert board.rate_hz == 20000.0
    assert board.info()["board"] in ("virtual", "emulated")
    text = board.status_text()
    assert text.startswith("board: ") and "state: parked" in text


def test_info_tells_what_the_board_has(board):
    i = board.info()
    assert i["axes"] == 1 and i["front_end"] == "internal"
    assert i["protocol"] >= 11 and i["rate_hz"] == 20000
    assert i["limits"]["setpoint_max_V"] == 150.0 and i["limits"]["step_max_V"] > 0
    # The factory model: open loop, no declared dynamics, no damping or shaping.
    assert i["features"] == {
        "closed_loop": False,
        "dynamics": False,
        "damping": False,
        "shaping": False,
        "mass_ratio": False,
        "bench": True,
    }
    assert "Move" in i["commands"] and "Bench" in i["commands"]
    assert i["settings"] == [
        "/stage/0/loop_mode",
        "/stage/0/compensated",
        "/stage/0/trigger/mode",
        "/stage/0/trigger/step_nm",
        "/stage/0/trigger/band_nm",
        "/stage/0/trigger/low_nm",
        "/stage/0/trigger/high_nm",
        "/stage/0/trigger/pulse_ticks",
        "/stage/0/trigger_in",
        "/supervise_ms",
    ]


def test_an_emulator_runs_a_given_firmware_and_names_a_missing_one(emulator):
    # An installed package without the source tree runs a built ELF.
    elf = ROOT / "target" / "thumbv7em-none-eabihf" / "firmware" / "fpi-firmware"
    with pf.Emulator(firmware=elf, link="uart") as e, pf.Board(e.port) as b:
        i = b.info()
        assert i["board"] == "emulated" and i["link"] == "uart"
    with pytest.raises(Exception) as missing:
        pf.Emulator(firmware=ROOT / "no-such-firmware.elf")
    assert "no-such-firmware.elf" in str(missing.value) and "not a file" in str(missing.value)


def test_move_and_wait_on_target(board):
    tick = board.move(20.0, speed=1000.0)
    assert tick > 0
    x = board.wait_on_target(timeout=10.0)
    assert abs(x - 20.0) <= 0.1
    assert board.on_target()
    s = board.status()
    assert s["state"] == "running" and s["source"] == "hold"
    assert s["reference_um"] == pytest.approx(20.0, abs=1e-4)
    assert abs(board.position() - 20.0) <= 0.1


def test_a_refusal_carries_the_boards_reason(board):
    with pytest.raises(pf.BoardError) as e:
        board.move(45.0)
    assert "outside the stroke" in e.value.reason
    assert "45.000" in e.value.reason
    assert e.value.code != "Fault"
    # The factory model has no [feedback] section: the loop cannot close.
    with pytest.raises(pf.BoardError):
        board.loop("closed")


def test_bad_arguments_name_the_argument(board):
    with pytest.raises(ValueError, match=r"^speed 1e-30 µm/s: below the link's resolution"):
        board.move(10.0, speed=1e-30)
    with pytest.raises(ValueError, match=r"^speed .*above 0"):
        board.move(10.0, speed=-5.0)
    with pytest.raises(ValueError, match=r"^target_um "):
        board.move(float("nan"))
    with pytest.raises(ValueError, match=r"^freq_hz 10000: at or above half"):
        board.wave("sine", amplitude_um=5, offset_um=20, freq_hz=10000)
    with pytest.raises(ValueError, match=r'^shape "square": sine, triangle or cosine'):
        board.wave("square", amplitude_um=5, offset_um=20, freq_hz=5)
    with pytest.raises(ValueError, match=r'^mode "shut": open, closed or feedback'):
        board.loop("shut")
    with pytest.raises(ValueError, match=r'^mode "sideways"'):
        board.drive("sideways")
    with pytest.raises(ValueError, match=r"^seconds "):
        board.record(seconds=0.0)
    with pytest.raises(ValueError, match=r"^points_um"):
        board.stream([1.0, float("inf")])
    with pytest.raises(TypeError, match="target_um"):
        board.move("twenty")
    with pytest.raises(TypeError, match="points_um"):
        board.stream([[1.0, 2.0], [3.0, 4.0]])
    with pytest.raises(ValueError, match=r"^analog_v "):
        board.bench(analog_v=5.0)
    # Nothing reached the board as a command.
    assert board.status()["state"] == "parked"


def test_wave_and_record_give_the_csv_columns(board):
    board.move(5.0)
    board.wait_on_target(timeout=10.0)
    board.wave("sine", amplitude_um=15, offset_um=20, freq_hz=15, cycles=0)
    rec = board.record(seconds=0.2, decimation=20)
    assert list(rec) == COLUMNS
    n = len(rec["t_s"])
    assert 195 <= n <= 200
    assert all(len(v) == n and v.dtype == np.float64 for v in rec.values())
    assert np.allclose(np.diff(rec["t_s"]), 20 / 20000.0)
    # The sine's swing after its approach (the reference spans at most 5–35 µm).
    assert rec["x_ref_um"].min() >= 4.99 and rec["x_ref_um"].max() <= 35.01
    assert rec["voltage_V"].max() > rec["voltage_V"].min()
    board.hold()
    assert board.status()["source"] == "hold"


def test_stream_plays_every_point(board):
    board.move(10.0)
    board.wait_on_target(timeout=10.0)
    x = 10.0 + 5.0 * np.sin(np.linspace(0, 2 * np.pi, 300))
    r = board.stream(x, interval=20)
    assert r["points"] == 300
    assert r["underrun_ticks"] == 0 and r["armed"] is False
    s = board.status()
    assert s["reference_um"] == pytest.approx(x[-1], abs=1e-3)
    assert s["supervision_ms"] == 0.0


def interrupt_after(seconds):
    t = threading.Timer(seconds, _thread.interrupt_main)
    t.start()
    return t


def test_ctrl_c_stops_record_and_keeps_what_was_recorded(board):
    board.move(10.0)
    board.wait_on_target(timeout=10.0)
    t = interrupt_after(0.4)
    with pytest.raises(pf.Interrupted) as e:
        board.record(seconds=30.0, decimation=20)
    t.join()
    assert isinstance(e.value, KeyboardInterrupt)
    done = e.value.done
    assert list(done) == COLUMNS
    assert 0 < len(done["t_s"]) < 30.0 * 1000
    s = board.status()
    assert s["recorder"]["recording"] is False
    assert s["state"] == "running"  # the stage left as it was


def test_ctrl_c_stops_a_stream_with_the_board_holding(board):
    board.move(10.0)
    board.wait_on_target(timeout=10.0)
    x = 10.0 + 5.0 * np.sin(np.linspace(0, 20 * np.pi, 10000))  # 10 s at 1 kHz
    t = interrupt_after(0.5)
    with pytest.raises(pf.Interrupted) as e:
        board.stream(x, interval=20)
    t.join()
    assert 0 < e.value.done["points"] < len(x)
    s = board.status()
    assert s["source"] == "hold"
    assert s["state"] == "running"
    assert s["supervision_ms"] == 0.0
    # Still holding later: the host's silence does not park it.
    r0 = s["reference_um"]
    board.wait_on_target(timeout=10.0)
    assert board.status()["reference_um"] == r0


def wait_parked(board):
    for _ in range(500):
        s = board.status()
        if s["state"] == "parked" and s["setpoint_V"] == s["model"]["safe_V"]:
            return
        time.sleep(0.01)
    raise AssertionError(f"not parked: {s}")


def test_load_a_firmware_model_when_parked(board):
    model = ROOT / "firmware" / "model" / "stage-a.toml"
    board.move(10.0)
    board.wait_on_target(timeout=10.0)
    with pytest.raises(pf.BoardError):
        board.load(model)  # the stage is not parked
    board.safe()
    wait_parked(board)
    r = board.load(model)
    assert len(r["crc"]) == 8 and r["bytes"] > 1000
    s = board.status()
    assert s["model"]["origin"] == "Received"
    assert s["model"]["crc"] == r["crc"]


def test_settings_by_key(board):
    st = board.settings
    assert st.keys() == [
        "stage/0/loop_mode",
        "stage/0/damping",
        "stage/0/shaping",
        "stage/0/compensated",
        "stage/0/trigger/mode",
        "stage/0/trigger/step_nm",
        "stage/0/trigger/band_nm",
        "stage/0/trigger/low_nm",
        "stage/0/trigger/high_nm",
        "stage/0/trigger/pulse_ticks",
        "stage/0/trigger_in",
        "supervise_ms",
    ]
    assert "stage.0.loop_mode" in st and "stage/0/lop" not in st
    # The factory model has no damping and no shaping.
    assert st.to_dict() == {
        "stage/0/loop_mode": "open",
        "stage/0/damping": None,
        "stage/0/shaping": None,
        "stage/0/compensated": True,
        "stage/0/trigger/mode": "off",
        "stage/0/trigger/step_nm": 1000,
        "stage/0/trigger/band_nm": 100,
        "stage/0/trigger/low_nm": 0,
        "stage/0/trigger/high_nm": 0,
        "stage/0/trigger/pulse_ticks": 1,
        "stage/0/trigger_in": "off",
        "supervise_ms": 0,
    }
    st["stage.0.compensated"] = False
    assert board.status()["compensated"] is False
    st["stage/0/compensated"] = True
    assert st["stage/0/compensated"] is True
    st["supervise_ms"] = 250
    assert st["supervise_ms"] == 250
    st["supervise_ms"] = 0
    # The named method's check: no [feedback], no closed loop.
    with pytest.raises(pf.BoardError, match="no \\[feedback\\] section"):
        st["stage/0/loop_mode"] = "closed"
    with pytest.raises(pf.BoardError, match="no such section"):
        st["stage/0/damping"] = False
    with pytest.raises(pf.BoardError, match="not a value of this setting's type"):
        st["stage/0/compensated"] = "yes"
    with pytest.raises(KeyError, match="no setting"):
        st["stage/0/lop"]
    assert st.describe("supervise_ms")["unit"] == "ms"


def test_step_is_scored_from_the_recording(board):
    # Every tick does not fit the UART's rate (the `virtual` board's): the
    # error names the Python argument.
    if board.info()["link"] == "uart":
        with pytest.raises(ValueError, match=r"decimation 31 or more fits.*raise decimation\)$"):
            board.step(10.0, 20.0, seconds=0.03)
    r = board.step(10.0, 20.0, seconds=0.1, decimation=40)
    for key in ("rise_ms", "overshoot_um", "settle_ms", "final_error_um", "governed_ticks"):
        assert key in r, r.keys()
    rec = r["recording"]
    assert len(rec["t_s"]) > 40 and rec["x_ref_um"][-1] == pytest.approx(20.0, abs=1e-3)
    # Open loop on the factory model's own stage: a fraction of a µm.
    assert abs(r["final_error_um"]) < 0.5, r
    assert r["settle_ms"] is not None and r["settle_ms"] < 10.0, r
    with pytest.raises(pf.BoardError, match="outside the stroke"):
        board.step(10.0, 45.0, decimation=40)


def test_frf_measures_the_response_through_the_board(board):
    with pytest.raises(ValueError, match=r"^points 3: 8 to 400 points$"):
        board.frf(points=3)
    with pytest.raises(ValueError, match=r"^to_hz 50: above from_hz 100$"):
        board.frf(from_hz=100.0, to_hz=50.0)
    f = board.frf(from_hz=100.0, to_hz=1000.0, points=8, zoom_points=0, amplitude_um=0.1)
    assert len(f["f_hz"]) == 8
    assert f["f_hz"][0] == pytest.approx(100.0) and f["f_hz"][-1] == pytest.approx(1000.0)
    assert f["x"].dtype.kind == "c" and len(f["x"]) == 8
    # Well below the stage's mode the compensated open loop passes the command.
    assert 0.7 < abs(f["x"][0]) < 1.3, f["x"]
    assert board.status()["source"] == "hold"


def test_analog_follows_the_input_and_supervision_parks(board):
    board.bench(analog_v=1.65)
    board.analog()
    time.sleep(0.3)
    s = board.status()
    assert s["source"] == "analog"
    lo, hi = s["model"]["stroke_um"]
    # 1.65 V of 3.3 V: the middle of the stroke.
    assert s["reference_um"] == pytest.approx((lo + hi) / 2, abs=0.5)
    board.hold()
    board.supervise(250)
    assert board.status()["supervision_ms"] == pytest.approx(250.0, abs=0.1)
    assert board.settings["supervise_ms"] == 250
    board.supervise(0)
    assert board.status()["supervision_ms"] == 0.0


def test_load_errors(board):
    with pytest.raises(FileNotFoundError):
        board.load("no-such-model.toml")
    with pytest.raises(ValueError, match="a CSV table .*, not a model"):
        board.load(DATA / "stage-a" / "fem.csv.gz")


def test_a_fault_is_a_board_error(board):
    board.bench(sensor="open")
    with pytest.raises(pf.BoardError) as e:
        board.move(10.0)
    assert e.value.code == "Fault"
    assert "force" in e.value.reason
    assert board.status()["state"] == "fault"
    board.bench(sensor="ok")
    board.clear_fault()
    assert board.status()["state"] == "parked"


def test_each_axis_of_a_board_of_several_is_its_own_board_object():
    with pf.Board("virtual:usb:xy-built") as b:
        assert b.axis == "x"
        axes = b.axes
        assert sorted(axes) == ["x", "y"]
        y = axes["y"]
        assert y.axis == "y" and y.port == b.port
        y.move(10.0, speed=1000.0)
        # Open loop, the factory model on the stage as built: within 0.6 µm.
        assert abs(y.wait_on_target(timeout=10.0, tolerance_um=0.6) - 10.0) <= 0.6
        sy, sx = y.status(), b.status()
        assert sy["axis"] == "y" and sy["state"] == "running"
        assert sy["reference_um"] == pytest.approx(10.0, abs=1e-4)
        assert sx["axis"] == "x" and sx["state"] == "parked"
        assert sx["fault_axis"] is None
        r = b.raster("x", "y", freq_hz=50.0, lines=4, from_um=5.0, to_um=35.0)
        assert set(r["x"]) >= {"t_s", "x_ref_um", "x_fhps_um"}
        assert len(r["x"]["t_s"]) == len(r["y"]["t_s"]) > 800
        assert r["y"]["x_ref_um"][-1] == pytest.approx(35.0, abs=1e-4)
        assert r["on_truth"] and r["missing"] == 0
        # Open loop on the factory model: the stage as built is a few % off.
        assert 0.0 < r["fast_rms_pct"] < 10.0
        with pytest.raises(ValueError, match="fast"):
            b.raster("w", "y", freq_hz=50.0, lines=4, from_um=5.0, to_um=35.0)
        t = b.move(x=12.0, y=22.0)
        assert t > 0
        axes["y"].wait_on_target(timeout=10.0, tolerance_um=0.6)
        assert b.status()["reference_um"] == pytest.approx(12.0, abs=1e-4)
        assert y.status()["reference_um"] == pytest.approx(22.0, abs=1e-4)
        with pytest.raises(TypeError, match="not both"):
            b.move(10.0, x=12.0)
    with pf.Board("virtual") as one:
        assert list(one.axes) == ["x"]


def test_context_manager_closes_the_link():
    with pf.Board("virtual") as b:
        assert not b.closed
    assert b.closed
    with pytest.raises(pf.LinkError, match="closed"):
        b.status()


def test_a_port_that_cannot_be_opened_is_a_link_error():
    with pytest.raises(pf.LinkError, match="serial port"):
        pf.Board("/dev/no-such-fpi-board")
    with pytest.raises(pf.LinkError):
        pf.Board("tcp:not a host:1")


def test_a_board_that_closes_the_connection_is_a_link_error():
    import socket

    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    port = srv.getsockname()[1]

    def serve():
        c, _ = srv.accept()
        c.close()

    t = threading.Thread(target=serve)
    t.start()
    with pytest.raises(pf.LinkError):
        pf.Board(f"tcp:127.0.0.1:{port}")
    t.join()
    srv.close()


def test_the_emulated_board_lost_is_a_link_error():
    if not pf.qemu_available():
        pytest.skip("qemu-system-arm is not installed")
    e = pf.Emulator()
    b = pf.Board(e.port)
    assert b.status()["state"] == "parked"
    e.close()
    with pytest.raises(pf.LinkError):
        b.status()
    b.close()


def test_the_emulator_takes_a_front_end():
    with pytest.raises(ValueError, match="internal.*precision"):
        pf.Emulator(frontend="sigma-delta")
    if not pf.qemu_available():
        pytest.skip("qemu-system-arm is not installed")
    with pf.Emulator(frontend="precision") as e:
        with pf.Board(e.port) as b:
            assert b.status()["state"] == "parked"
            # The hello names the front end the board converts with.
            assert b.info()["front_end"] == "precision"
            # The precision front end's 16-bit force channel: the rest preload
            # read to finer than the internal 12-bit channel's 0.125 N steps.
            # One reading in 16 lands on that grid by chance (the sensor's
            # noise moves it): one of 20 readings must fall between.
            forces = [b.status()["force_N"] for _ in range(20)]
            off_grid = [f for f in forces if abs(f / 0.125 - round(f / 0.125)) > 1e-6]
            assert off_grid, forces


def test_long_calls_release_the_gil():
    """Another Python thread runs while `record` waits on the board."""
    with pf.Board("virtual") as b:
        ticks = []
        stop = threading.Event()

        def count():
            while not stop.is_set():
                ticks.append(1)
                stop.wait(0.01)

        t = threading.Thread(target=count)
        t.start()
        b.record(seconds=0.5, decimation=100)
        stop.set()
        t.join()
        assert len(ticks) >= 20


def test_autotune_takes_its_options_and_refines_the_feedforward(tmp_path):
    """`autotune` on the in-process board with the stage as built: the table
    names the trials asked for, and the design's options reach it (designed
    for a force sensor's σ of 1 N, the stage's being 0.15 N, the damping
    target is lowered and the table says so); the tuned model is written; a
    negative count of trials is refused before anything runs."""
    model = ROOT / "firmware" / "model" / "stage-a.toml"
    with pf.Board("virtual:usb") as b:
        b.bench(stage="built")
        with pytest.raises(OverflowError):
            b.autotune(model, tmp_path / "never.toml", trials=-1)
        table = b.autotune(model, tmp_path / "tuned.toml", trials=1, force_noise_n=1.0)
        assert "1 trial(s)" in table, table
        assert "lowered for the noise" in table, table
        assert "(asked 0.50" in table, table
        # The tuned model runs: its damping and shaping switch off and on, by
        # name and by key (in open loop: its gains need the damping closed).
        b.loop("open")
        s = b.status()
        assert s["damping"] is True and s["shaping"] is True
        assert isinstance(b.damping(False), int)
        assert b.status()["damping"] is False
        assert b.settings["stage/0/damping"] is False
        b.damping("on")
        b.shaping("off")
        assert b.status()["shaping"] is False
        b.settings["stage/0/shaping"] = True
        assert b.status()["shaping"] is True
        # Closed on the mode, the damping stays on: the board says why.
        b.loop("closed")
        with pytest.raises(pf.BoardError, match="without damping"):
            b.damping(False)
        b.loop("open")
        text = (tmp_path / "tuned.toml").read_text()
        assert "taps" in text and "preview_ticks = 5" in text
        with pytest.raises(ValueError, match="target_damping 2: between 0 and 1"):
            b.autotune(model, tmp_path / "never.toml", target_damping=2.0)


def test_motions_record_every_tick_of_what_they_do(board):
    """`move`, `wave` and `stream` with `record=True`: every tick from the
    command's, the true position included; a link that cannot carry every
    tick (the UART) is refused before anything moves."""
    if board.info()["link"] != "usb":
        with pytest.raises(ValueError, match="record"):
            board.move(10.0, record=True)
        assert board.status()["state"] == "parked"
        return
    def every_tick(rec):
        assert list(rec) == COLUMNS
        assert len(rec["t_s"]) > 100
        assert np.allclose(np.diff(rec["t_s"]), 1 / 20000.0)
        assert np.all(np.isfinite(rec["x_fhps_um"]))

    m = board.move(10.0, speed=2000.0, record=True)
    every_tick(m["recording"])
    assert m["recording"]["t_s"][0] == pytest.approx(m["tick"] / 20000.0)
    assert m["recording"]["x_ref_um"][-1] == pytest.approx(10.0, abs=1e-3)
    w = board.wave("sine", amplitude_um=2, offset_um=12, freq_hz=40, record=True, seconds=0.1)
    every_tick(w["recording"])
    assert len(w["recording"]["t_s"]) == 2000
    board.hold()
    with pytest.raises(ValueError, match="seconds"):
        board.wave("sine", amplitude_um=2, offset_um=12, freq_hz=40, record=True)
    x = 12.0 + 3.0 * np.sin(np.linspace(0, 2 * np.pi, 150))
    r = board.stream(x, interval=20, record=True)
    assert r["points"] == 150
    every_tick(r["recording"])
    assert len(r["recording"]["t_s"]) >= 3000 + 1000


def test_a_live_recording_reads_while_the_board_moves(board):
    """PI's DRC → motion → DRR?: the recorder armed before a wave, read in
    blocks while the wave runs and other commands are sent, then stopped:
    the whole recording, every 50th tick without a gap (what the UART
    carries), the wave from before
    its first tick."""
    board.move(10.0)
    board.wait_on_target(timeout=10.0)
    rec = board.record_start(decimation=50)
    assert rec.running
    started = board.wave("sine", amplitude_um=2, offset_um=12, freq_hz=40, cycles=0)
    blocks = []
    deadline = time.time() + 30.0
    while sum(len(b["t_s"]) for b in blocks) < 300 and time.time() < deadline:
        time.sleep(0.02)
        blocks.append(rec.read())
    # Commands go on meanwhile; those that use the recorder wait for it.
    assert board.status()["source"] == "wave"
    with pytest.raises(pf.BoardError, match="live recording"):
        board.record(seconds=0.1)
    with pytest.raises(pf.BoardError, match="runs already"):
        board.record_start()
    whole = rec.stop()
    board.hold()
    assert not rec.running
    assert list(whole) == COLUMNS
    read = np.concatenate([b["t_s"] for b in blocks])
    assert len(read) >= 300
    assert np.array_equal(whole["t_s"][: len(read)], read)
    assert np.allclose(np.diff(whole["t_s"]), 50 / 20000.0)
    assert (rec.gaps, rec.missing, rec.dropped) == (0, 0, 0)
    assert rec.samples == len(whole["t_s"])
    assert whole["t_s"][0] * 20000.0 <= started
    assert whole["x_ref_um"].max() > 13.5
    with pytest.raises(pf.BoardError, match="stopped already"):
        rec.stop()
    # The recorder is the board's again.
    assert len(board.record(seconds=0.05)["t_s"]) > 0


def test_the_trigger_output_is_recorded_in_its_column(board):
    """The trigger output (PI: ``CTO``): a 100-tick pulse every 0.5 µm of a
    10 µm move, recorded in the ``trigger`` column; its levels are settings
    too, and bad ones name the argument."""
    board.move(10.0)
    board.wait_on_target(timeout=10.0)
    board.trigger("travel", step_um=0.5, pulse_ticks=100)
    assert board.settings["stage/0/trigger/step_nm"] == 500
    assert board.settings["stage/0/trigger/mode"] == "travel"
    rec = board.record_start(decimation=20, signals=["x_sensor_um", "trigger"])
    board.move(20.0, speed=20.0)
    board.wait_on_target(timeout=60.0)
    whole = rec.stop()
    assert list(whole) == ["t_s", "x_sensor_um", "trigger"]
    line = whole["trigger"]
    rising = np.count_nonzero((line[1:] > 0) & (line[:-1] == 0))
    assert 19 <= rising <= 21, rising
    board.settings["stage/0/trigger/mode"] = "off"
    with pytest.raises(ValueError, match=r"^step_um 0: above 0 µm"):
        board.trigger("travel", step_um=0.0)
    with pytest.raises(ValueError, match=r'^mode "sometimes": off, travel'):
        board.trigger("sometimes")
    with pytest.raises(pf.BoardError, match="low edge must not lie above its high edge"):
        board.trigger("window", low_um=5.0, high_um=4.0)
    assert board.settings["stage/0/trigger/mode"] == "off"


def test_the_trigger_input_starts_an_armed_recording_and_wave(board):
    """PI's WGO with start at the trigger input: a recording and a wave
    ordered while the input starts both wait, armed, until a pulse on the
    (emulated) input starts them on its edge."""
    board.move(20.0)
    board.wait_on_target(timeout=10.0)
    board.trigger_in("both")
    rec = board.record_start(decimation=20, signals=["x_ref_um", "trigger"])
    board.wave("sine", amplitude_um=1, offset_um=20, freq_hz=50, cycles=2)
    s = board.status()
    assert s["source"] == "hold" and s["motion_armed"] and s["record_armed"]
    board.bench(trigger_in_ticks=40)
    deadline = time.time() + 30.0
    while board.status()["source"] != "hold" or board.status()["motion_armed"]:
        assert time.time() < deadline
        time.sleep(0.05)
    whole = rec.stop()
    assert whole["x_ref_um"].max() > 20.9
    # The recording starts on the edge: its first samples see the input high.
    assert whole["trigger"][0] == 2
    board.trigger_in("off")
    with pytest.raises(ValueError, match=r'^starts "always": off, motion, recorder or both'):
        board.trigger_in("always")


def test_a_live_recording_checks_its_arguments_and_can_keep_only_what_is_unread(board):
    with pytest.raises(ValueError, match=r'^signals: "nope" is no recorded column'):
        board.record_start(signals=["nope"])
    with pytest.raises(ValueError, match=r"^decimation 0"):
        board.record_start(decimation=0)
    if board.info()["link"] != "usb":
        with pytest.raises(ValueError, match=r"^decimation 1: the stream needs"):
            board.record_start(decimation=1)
    with board.record_start(decimation=50, signals=["x_ref_um"], keep=False) as rec:
        time.sleep(0.1)
        first = rec.read()
        time.sleep(0.1)
        rest = rec.stop()
    assert list(first) == ["t_s", "x_ref_um"]
    assert len(first["t_s"]) > 0 and len(rest["t_s"]) > 0
    assert rest["t_s"][0] == pytest.approx(first["t_s"][-1] + 50 / 20000.0)
    # A recorder left running by a `with` block is stopped at its end.
    with board.record_start(decimation=50) as rec:
        pass
    assert not rec.running
    assert len(board.record(seconds=0.05)["t_s"]) > 0


def test_two_scripts_share_one_board_through_the_hub():
    """`fpi board serve`: one process owns the board's link; a script drives
    the stage while another records it live, and the recorder's script's
    motion is refused naming the driver."""
    import signal
    import socket
    import subprocess

    from conftest import fpi_command

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    hub = subprocess.Popen(
        fpi_command() + ["board", "--port", "virtual:usb", "serve", "--listen", f"127.0.0.1:{port}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        assert "serving" in hub.stdout.readline()
        address = f"tcp:127.0.0.1:{port}"
        with pf.Board(address) as driver, pf.Board(address) as watcher:
            driver.move(12.0)
            driver.wait_on_target(timeout=10.0)
            rec = watcher.record_start(decimation=20)
            driver.wave("sine", amplitude_um=2, offset_um=12, freq_hz=40)
            time.sleep(0.5)
            with pytest.raises(pf.BoardError, match=r"the motion is held by client 1"):
                watcher.move(5.0)
            whole = rec.stop()
            driver.hold()
        assert len(whole["t_s"]) > 300
        assert np.allclose(np.diff(whole["t_s"]), 20 / 20000.0)
        assert whole["x_ref_um"].max() > 13.5
        assert (rec.gaps, rec.dropped) == (0, 0)
    finally:
        hub.send_signal(signal.SIGINT)
        hub.wait(timeout=10)


def _file_of_two_axes(path):
    """The factory model on both axes and a coupling, as `fpi board autotune`
    of every axis writes a file of several axes."""
    model = (ROOT / "firmware" / "model" / "stage-a.toml").read_text()
    text = [
        'format = "piezo-fpi-axes/1"',
        "[coupling]",
        "sensor_crosstalk = 0.002",
        "parasitic = [[0.0, 0.02], [0.015, 0.0]]",
        "preload_n_per_um = [[0.0, 0.5], [0.5, 0.0]]",
    ]
    for axis in ("x", "y"):
        text.append(f"[{axis}]")
        for line in model.splitlines():
            if line.startswith("[["):
                line = f"[[{axis}." + line[2:]
            elif line.startswith("["):
                line = f"[{axis}." + line[1:]
            text.append(line)
    path.write_text("\n".join(text) + "\n")


def test_a_file_of_several_axes_loads_whole(tmp_path):
    out = tmp_path / "xy.toml"
    _file_of_two_axes(out)
    with pf.Board("virtual:xy-built") as b:
        loaded = b.load(out)
        assert loaded["axes"] == 2 and len(loaded["tick"]) == 2
    with pf.Board("virtual") as one:
        with pytest.raises(pf.BoardError, match="2 axes"):
            one.load(out)
        # Autotune of every axis wants a board of several.
        with pytest.raises(Exception, match="2 axes"):
            one.autotune(out, tmp_path / "never.toml", every_axis=True)
