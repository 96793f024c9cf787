"""The examples run: the scan-and-log script, as a lab would run it, on the
in-process board, with matplotlib and without it."""

import os
import subprocess
import sys
from pathlib import Path

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def test_scan_and_log_runs(tmp_path):
    r = subprocess.run(
        [sys.executable, str(EXAMPLES / "scan_and_log.py"), "virtual", "--out", str(tmp_path), "--lines", "3"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    assert "line 2: centre" in r.stdout
    png = (tmp_path / "scan.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    log = (tmp_path / "scan.csv").read_text().splitlines()
    assert log[0] == "t_s,voltage_V,force_N,x_ref_um,x_est_um,status,x_fhps_um,x_sensor_um,line"
    assert len(log) > 100


def test_scan_and_log_without_matplotlib_logs_and_says_how_to_plot(tmp_path):
    """On a plain `pip install ./python` (no `examples` extra) the example still
    logs its CSV, and names the extra that brings the plot."""
    blocker = tmp_path / "no-matplotlib" / "matplotlib"
    blocker.mkdir(parents=True)
    (blocker / "__init__.py").write_text('raise ImportError("matplotlib is blocked for this test")\n')
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(blocker.parent), os.environ.get("PYTHONPATH")])))
    out = tmp_path / "out"
    r = subprocess.run(
        [sys.executable, str(EXAMPLES / "scan_and_log.py"), "virtual", "--out", str(out), "--lines", "2"],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )
    assert r.returncode == 0, r.stderr
    assert "no plot: matplotlib is not installed" in r.stdout and "[examples]" in r.stdout
    assert len((out / "scan.csv").read_text().splitlines()) > 50
    assert not (out / "scan.png").exists()
