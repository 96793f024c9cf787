"""The method from Python against the `fpi` CLI on the shared datasets: the same
model file, and the same numbers to the last digit the CLI prints; and the
errors of bad arguments."""

import numpy as np
import pytest

import piezo_fpi as pf

from conftest import DATA, read_csv

RIG = [DATA / "pea-rig" / "preload_050N_sine_05Hz.csv.gz", DATA / "pea-rig" / "preload_100N_sine_05Hz.csv.gz"]
FEM = DATA / "stage-a" / "fem.csv.gz"
RUN = DATA / "stage-a" / "sine_05Hz.csv.gz"


def csv_lines(path):
    import gzip

    opener = gzip.open if str(path).endswith(".gz") else open
    with opener(path, "rt") as f:
        return f.read().splitlines()


def as_cli_prints(columns: dict) -> list:
    """The CSV `fpi` writes for these columns (`{:.6}` each)."""
    names = list(columns)
    rows = zip(*(columns[n] for n in names))
    return [",".join(names)] + [",".join(f"{v:.6f}" for v in row) for row in rows]


@pytest.fixture(scope="module")
def cli_model(tmp_path_factory, fpi):
    out = tmp_path_factory.mktemp("cli") / "fpi.toml"
    fpi("calibrate", "--kind", "fpi", "--rig", *RIG, "--out", out)
    return out


def test_calibrate_writes_the_clis_model_file(cli_model, tmp_path):
    runs = [read_csv(p) for p in RIG]
    m = pf.calibrate(runs, kind="fpi", names=[str(p) for p in RIG])
    assert m.kind == "fpi"
    assert 0 < m.rmse_um < 1.0
    assert [f["file"] for f in m.per_file] == [p.name[: -len(".gz")] for p in RIG]
    m.save(tmp_path / "py.toml")
    assert (tmp_path / "py.toml").read_text() == cli_model.read_text()


def test_model_file_round_trip(cli_model, tmp_path):
    m = pf.Model.load(cli_model)
    m.save(tmp_path / "again.toml")
    assert (tmp_path / "again.toml").read_text() == cli_model.read_text()
    assert "fpi" in repr(m)


def test_predict_gives_the_clis_numbers(cli_model, tmp_path, fpi):
    out = tmp_path / "pred.csv"
    fpi("predict", "--model", cli_model, "--fem", FEM, "--drive", RUN, "--out", out)
    run = read_csv(RUN)
    p = pf.Model.load(cli_model).predict(fem=FEM, t_s=run["t_s"], voltage_V=run["voltage_V"])
    assert list(p) == ["t_s", "voltage_V", "x_pea_um", "preload_N", "x_fhps_um"]
    assert as_cli_prints(p) == csv_lines(out)


def test_invert_gives_the_clis_numbers(cli_model, tmp_path, fpi):
    out = tmp_path / "drive.csv"
    fpi("invert", "--model", cli_model, "--fem", FEM, "--target", RUN, "--out", out)
    run = read_csv(RUN)
    u = pf.Model.load(cli_model).invert(fem=FEM, t_s=run["t_s"], x_fhps_um=run["x_fhps_um"])
    assert as_cli_prints(u) == csv_lines(out)


def test_predict_then_invert_comes_back(cli_model):
    m = pf.Model.load(cli_model)
    t = np.arange(0, 0.4, 1e-3)
    target = 10.0 + 8.0 * np.sin(2 * np.pi * 5 * t)
    u = m.invert(fem=FEM, t_s=t, x_fhps_um=target)
    x = m.predict(fem=FEM, t_s=t, voltage_V=u["voltage_V"])["x_fhps_um"]
    assert np.max(np.abs(x - target)) < 1e-6


def test_a_board_recording_calibrates_as_it_is():
    """A recording's columns go to `calibrate` unchanged (x_fhps_um as the
    displacement, force_N as the force). The method assumes a recording that
    starts at rest; `record` starts about 60 ms into the wave (the command is
    checked for faults first), so the wave is slow: 0.2 µm from rest by then (at
    2 Hz it was 3–4 µm, and the fit failed now and then)."""
    # 1 000 samples/s: the USB link's rate (the UART would drop most of them).
    with pf.Board("virtual:usb") as b:
        b.wave("cosine", amplitude_um=15, offset_um=15, freq_hz=0.5, cycles=1)
        rec = b.record(seconds=2.0, decimation=20)
    m = pf.calibrate([rec], kind="efpi")
    assert m.kind == "efpi"
    assert m.per_file[0]["samples"] == len(rec["t_s"]) == 2000
    swing = np.ptp(rec["x_fhps_um"])
    assert swing > 25.0
    # Measured 0.022–0.027 µm (three runs); 0.15 µm allows five times that.
    assert m.rmse_um < 0.005 * swing


def test_calibrate_errors():
    run = read_csv(RIG[0])
    with pytest.raises(ValueError, match="^kind: "):
        pf.calibrate([run], kind="nonsense")
    with pytest.raises(TypeError, match=r"runs\[0\]: a dict of arrays"):
        pf.calibrate([[1, 2, 3]])
    with pytest.raises(ValueError, match=r"runs\[0\]: no column 'voltage_V'|no column \"voltage_V\""):
        pf.calibrate([{"t_s": run["t_s"]}])
    with pytest.raises(ValueError, match="no recordings"):
        pf.calibrate([])
    with pytest.raises(ValueError, match="^compliance applies to"):
        pf.calibrate([run], kind="pi", compliance=0.02)
    with pytest.raises(ValueError, match=r"^rows 1-5: 5 rows"):
        pf.calibrate([run], kind="fpi", rows=(1, 5))
    short = dict(run)
    short["force_N"] = short["force_N"][:-1]
    with pytest.raises(ValueError, match="different lengths"):
        pf.calibrate([short])
    with pytest.raises(TypeError, match=r"runs\[0\]\['t_s'\]|t_s"):
        pf.calibrate([dict(run, t_s="abc")])


def test_predict_and_invert_errors(cli_model):
    m = pf.Model.load(cli_model)
    t = np.arange(0, 0.1, 1e-3)
    u = np.full_like(t, 50.0)
    with pytest.raises(FileNotFoundError):
        m.predict(fem="no-such-fem.csv", t_s=t, voltage_V=u)
    bad = u.copy()
    bad[3] = np.nan
    with pytest.raises(ValueError, match=r"^voltage_V\[3\] = NaN: not a finite number|^voltage_V\[3\] = nan"):
        m.predict(fem=FEM, t_s=t, voltage_V=bad)
    with pytest.raises(ValueError, match=r"^t_s\[5\] = .* does not increase"):
        tt = t.copy()
        tt[5] = tt[4]
        m.predict(fem=FEM, t_s=tt, voltage_V=u)
    with pytest.raises(ValueError, match=r"^voltage_V\[0\] = 400 V is outside the model's input range"):
        m.predict(fem=FEM, t_s=t, voltage_V=np.full_like(t, 400.0))
    with pytest.raises(ValueError, match="samples"):
        m.predict(fem=FEM, t_s=t, voltage_V=u[:-1])
    with pytest.raises(TypeError, match="voltage_V"):
        m.predict(fem=FEM, t_s=t, voltage_V=None)
    with pytest.raises(ValueError, match="u_max"):
        m.invert(fem=FEM, t_s=t, x_fhps_um=np.full_like(t, 5.0), u_max=-1.0)
    with pytest.raises(FileNotFoundError):
        pf.Model.load("no-such-model.toml")
    with pytest.raises(ValueError, match="not a model|format"):
        pf.Model.load(FEM)


def test_predict_axes_gives_the_clis_numbers(cli_model, tmp_path, fpi):
    grid = DATA / "xy" / "fem_grid.csv.gz"
    # The drive as its file holds it (six decimals), so both read the same numbers.
    as_written = lambda v: np.array([float(f"{x:.6f}") for x in v])
    t = as_written(np.arange(2000) * 5e-5)
    ux = as_written(50 - 50 * np.cos(2 * np.pi * 5 * t))
    uy = as_written(50 - 50 * np.cos(2 * np.pi * 3 * t))
    drive = tmp_path / "drive.csv"
    lines = ["t_s,voltage_V@x,voltage_V@y"] + [f"{a:.6f},{b:.6f},{c:.6f}" for a, b, c in zip(t, ux, uy)]
    drive.write_text("\n".join(lines) + "\n")
    m = pf.Model.load(cli_model)
    for independent in (False, True):
        out = tmp_path / f"axes-{independent}.csv"
        args = ["axes", "predict", "--grid", grid, "--model", cli_model, "--drive", drive, "--out", out]
        fpi(*(args + (["--independent"] if independent else [])))
        p = pf.predict_axes(
            [m], grid=grid, t_s=t, voltages=[ux, uy], independent=independent
        )
        assert list(p)[:5] == ["t_s", "voltage_V@x", "x_pea_um@x", "preload_N@x", "x_fhps_um@x"]
        assert as_cli_prints(p) == csv_lines(out)
    with pytest.raises(ValueError, match="3 given for a grid of 2 stacks"):
        pf.predict_axes([m, m, m], grid=grid, t_s=t, voltages=[ux, uy])
    with pytest.raises(ValueError, match="the drive has 1 axes"):
        pf.predict_axes([m], grid=grid, t_s=t, voltages=[ux])


def read_axes_csv(path) -> dict:
    """A several-axis recording (`fpi axes record`): arrays by column, the
    `@x`/`@y` in the names kept."""
    with open(path, encoding="utf-8") as f:
        header = f.readline().strip().split(",")
    values = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return {name: values[:, k].copy() for k, name in enumerate(header)}


def test_refine_axes_gives_the_clis_corrections(cli_model, tmp_path, fpi):
    """`refine_axes` on a recording of the XY prototype: the corrections
    `fpi axes refine` writes, digit for digit; the refined models predict the
    run better; a run without a column is refused naming it."""
    grid = DATA / "xy" / "fem_grid.csv.gz"
    t = np.arange(4000) * 5e-5
    drive = tmp_path / "drive.csv"
    ux = 50 - 50 * np.cos(2 * np.pi * 5 * t)
    uy = 50 - 50 * np.cos(2 * np.pi * 3 * t)
    lines = ["t_s,voltage_V@x,voltage_V@y"] + [f"{a:.6f},{b:.6f},{c:.6f}" for a, b, c in zip(t, ux, uy)]
    drive.write_text("\n".join(lines) + "\n")
    rec = tmp_path / "built.csv"
    fpi("axes", "record", "--stage", "xy-built", "--drive", drive, "--out", rec)
    outs = [tmp_path / "x.toml", tmp_path / "y.toml"]
    fpi("axes", "refine", "--grid", grid, "--model", cli_model, "--run", rec, "--out", *outs)
    run = read_axes_csv(rec)
    m = pf.Model.load(cli_model)
    refined = pf.refine_axes([m], grid=grid, runs=[run], names=[str(rec)])
    assert len(refined) == 2 and m.fem_correction is None
    for r, out in zip(refined, outs):
        mine, cli = r.fem_correction, pf.Model.load(out).fem_correction
        assert mine["fem"] == str(grid) and mine["refined_on"] == [str(rec)]
        for key in ("stage_gain", "stage_offset_um", "preload_scale"):
            assert mine[key] == pytest.approx(cli[key], rel=1e-12, abs=1e-12), key
    voltages = [run["voltage_V@x"], run["voltage_V@y"]]
    err = lambda ms: [
        np.sqrt(np.mean((p - run[f"x_fhps_um@{a}"]) ** 2))
        for a, p in zip("xy", (lambda c: [c["x_fhps_um@x"], c["x_fhps_um@y"]])(
            pf.predict_axes(ms, grid=grid, t_s=run["t_s"], voltages=voltages)
        ))
    ]
    before, after = err([m]), err(refined)
    assert all(a < b for a, b in zip(after, before)), (before, after)
    del run["force_N@y"]
    with pytest.raises(ValueError, match='runs\\[0\\]: no column "force_N@y"'):
        pf.refine_axes([m], grid=grid, runs=[run])


def test_refine_gives_the_clis_correction(cli_model, tmp_path, fpi):
    """`Model.refine` on a run of stage A: the correction `fpi refine` writes,
    digit for digit, naming the FEM and the run; a run without force is
    refused naming the column."""
    out = tmp_path / "refined.toml"
    fpi("refine", "--model", cli_model, "--fem", FEM, "--run", RUN, "--out", out)
    run = read_csv(RUN)
    refined = pf.Model.load(cli_model).refine(fem=FEM, runs=[run], names=[str(RUN)])
    mine, cli = refined.fem_correction, pf.Model.load(out).fem_correction
    assert mine["fem"] == str(FEM) and mine["refined_on"] == [str(RUN)]
    for key in ("stage_gain", "stage_offset_um", "preload_scale"):
        assert mine[key] == pytest.approx(cli[key], rel=1e-12, abs=1e-12), key
    del run["force_N"]
    with pytest.raises(ValueError, match='runs\\[0\\]: no column "force_N"'):
        pf.Model.load(cli_model).refine(fem=FEM, runs=[run])
