"""Calibrate from recordings and upload: fit an efpi model on preload-rig
recordings (the project's datasets, read as arrays), save it, upload it with the
stage's FEM tables to the board, and check it there: a 5 Hz sine recorded by the
board's data recorder, and its tracking error.

    python calibrate_and_upload.py [PORT] [--out DIR]

PORT: "virtual:usb" (default), tcp:127.0.0.1:4545 (`cargo emulate`), /dev/ttyUSB0.
"""

import argparse
import time
from pathlib import Path

import numpy as np

import piezo_fpi as pf

DATA = Path(__file__).resolve().parents[2] / "tests-host" / "data"
RIG = [DATA / "pea-rig" / f"preload_{n:03d}N_sine_05Hz.csv.gz" for n in (50, 100, 150)]
FEM = DATA / "stage-a" / "fem.csv.gz"


def read_csv(path):
    a = np.genfromtxt(path, delimiter=",", names=True, dtype=np.float64, encoding="utf-8")
    return {name: np.asarray(a[name]) for name in a.dtype.names}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("port", nargs="?", default="virtual:usb")
    ap.add_argument("--out", default="calibrate-out")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    runs = [read_csv(p) for p in RIG]
    model = pf.calibrate(runs, kind="efpi", names=[p.name for p in RIG])
    print(f"{model!r}")
    for f in model.per_file:
        print(f"  {f['file']:<32} {f['samples']:6d} samples, RMSE {f['rmse_um']:.4f} µm")
    model.save(out / "efpi.toml")

    with pf.Board(args.port) as b:
        b.safe()
        while b.status()["setpoint_V"] != b.status()["model"]["safe_V"]:
            time.sleep(0.01)
        r = b.load(out / "efpi.toml", fem=FEM)
        print(f"uploaded model {r['crc']} ({r['bytes']} bytes) at tick {r['tick']}")
        b.move(5.0)
        b.wait_on_target(timeout=10.0)
        b.wave("sine", amplitude_um=12, offset_um=18, freq_hz=5, cycles=0)
        time.sleep(0.3)  # past the approach
        rec = b.record(seconds=0.4, decimation=20)
        b.hold()
        b.safe()

    err = rec["x_fhps_um"] - rec["x_ref_um"]
    print(f"on the board: tracking RMS {np.sqrt(np.mean(err**2)) * 1e3:.1f} nm, max {np.max(np.abs(err)) * 1e3:.1f} nm")


if __name__ == "__main__":
    main()
