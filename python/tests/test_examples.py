"""The examples run: the scan-and-log script, as a lab would run it, on the
in-process board."""

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
