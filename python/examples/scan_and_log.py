"""Scan and log: move to the start, raster the stroke line by line (one triangle
sweep per line, each line's centre a step higher), record every line with the
board's data recorder, log it to CSV and plot it to a PNG (with matplotlib:
`pip install "./python[examples]"`; without it, the CSV only).

    python scan_and_log.py [PORT] [--out DIR]

PORT: "virtual:usb" (the firmware in this process, its link paced as USB; the default), tcp:127.0.0.1:4545
(`cargo emulate`), or a serial device (/dev/ttyUSB0).
"""

import argparse
from pathlib import Path

import numpy as np

import piezo_fpi as pf


def pyplot():
    """matplotlib's pyplot drawing to files, or None (with a note) where
    matplotlib is missing: it comes with the package's `examples` extra."""
    try:
        import matplotlib
    except ImportError:
        print('no plot: matplotlib is not installed (pip install "./python[examples]", or pip install matplotlib)')
        return None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("port", nargs="?", default="virtual:usb")
    ap.add_argument("--out", default="scan-out", help="folder for scan.csv and scan.png")
    ap.add_argument("--lines", type=int, default=4)
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    half_swing_um, freq_hz = 4.0, 20.0  # one line: 4 µm either side, 50 ms
    centres_um = np.linspace(8.0, 28.0, args.lines)
    lines = []
    with pf.Board(args.port) as b:
        print(b.status_text())
        b.move(centres_um[0] - half_swing_um, speed=500.0)
        x = b.wait_on_target(timeout=10.0)
        print(f"at the start: {x:.4f} µm")
        for k, c in enumerate(centres_um):
            # The generator approaches the line's start, runs one period, holds.
            b.wave("triangle", amplitude_um=half_swing_um, offset_um=c, freq_hz=freq_hz, cycles=1)
            rec = b.record(seconds=1.0 / freq_hz + 0.02, decimation=10)
            rec["line"] = np.full(len(rec["t_s"]), float(k))
            lines.append(rec)
            err = rec["x_fhps_um"] - rec["x_ref_um"]
            print(f"line {k}: centre {c:5.2f} µm, {len(err)} samples, RMS error {np.sqrt(np.mean(err**2)) * 1e3:6.1f} nm")
        b.safe()

    log = {name: np.concatenate([r[name] for r in lines]) for name in lines[0]}
    header = ",".join(log)
    np.savetxt(out / "scan.csv", np.column_stack(list(log.values())), delimiter=",", header=header, comments="", fmt="%.6f")
    print(f"logged {len(log['t_s'])} samples to {out / 'scan.csv'}")

    plt = pyplot()
    if plt is None:
        return
    fig, (top, bottom) = plt.subplots(2, 1, sharex=True, figsize=(8, 6))
    t0 = log["t_s"][0]
    top.plot(log["t_s"] - t0, log["x_ref_um"], lw=1, label="reference")
    top.plot(log["t_s"] - t0, log["x_fhps_um"], lw=1, label="stage (true)")
    top.set_ylabel("position (µm)")
    top.legend()
    bottom.plot(log["t_s"] - t0, (log["x_fhps_um"] - log["x_ref_um"]) * 1e3, lw=1)
    bottom.set_ylabel("error (nm)")
    bottom.set_xlabel("board time (s)")
    fig.suptitle(f"raster of {args.lines} lines on {args.port}")
    fig.tight_layout()
    fig.savefig(out / "scan.png", dpi=100)
    print(f"plot: {out / 'scan.png'}")


if __name__ == "__main__":
    main()
