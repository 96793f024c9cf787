"""Closed-loop comparison: on the stage as built (it differs from the model
the board holds, and rings at 850 Hz), track a 15 Hz sine open loop (inverse
FPI feedforward only), then tune the loops through the board (`autotune`) and
track it again closed on the position sensor. Prints both errors and plots them
(with matplotlib: `pip install "./python[examples]"`).

    python closed_loop.py [PORT] [--out DIR]

PORT: "virtual:usb" (default) or tcp:127.0.0.1:4545 (`cargo emulate`): it needs the
emulated board's virtual bench to choose the stage as built.
"""

import argparse
import time
from pathlib import Path

import numpy as np

import piezo_fpi as pf

ROOT = Path(__file__).resolve().parents[2]
FACTORY = ROOT / "firmware" / "model" / "stage-a.toml"  # the model the firmware embeds


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


def parked(b):
    b.safe()
    while True:
        s = b.status()
        if s["state"] == "parked" and s["setpoint_V"] == s["model"]["safe_V"]:
            return
        time.sleep(0.01)


def track(b, label):
    b.move(5.0)
    b.wait_on_target(timeout=10.0)
    b.wave("sine", amplitude_um=12, offset_um=18, freq_hz=15, cycles=0)
    time.sleep(0.3)
    rec = b.record(seconds=0.2, decimation=4)
    b.hold()
    err = rec["x_fhps_um"] - rec["x_ref_um"]
    rms = np.sqrt(np.mean(err**2))
    print(f"{label:<34} RMS {rms * 1e3:7.1f} nm, max {np.max(np.abs(err)) * 1e3:7.1f} nm")
    return rec, rms


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("port", nargs="?", default="virtual:usb")
    ap.add_argument("--out", default="closed-loop-out")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    with pf.Board(args.port) as b:
        parked(b)
        print(b.bench(stage="built")[0])
        b.loop("open")
        opened, _ = track(b, "open loop (inverse FPI)")
        parked(b)
        print("tuning the loops through the board (half a minute) …")
        print(b.autotune(FACTORY, out / "tuned.toml"))
        b.loop("closed")
        closed, _ = track(b, "closed loop (feedback + inverse FPI)")
        parked(b)

    plt = pyplot()
    if plt is None:
        return
    fig, ax = plt.subplots(figsize=(8, 4))
    for rec, label in ((opened, "open loop"), (closed, "closed loop")):
        ax.plot(rec["t_s"] - rec["t_s"][0], (rec["x_fhps_um"] - rec["x_ref_um"]) * 1e3, lw=1, label=label)
    ax.set_xlabel("board time (s)")
    ax.set_ylabel("tracking error (nm)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "closed-loop.png", dpi=100)
    print(f"plot: {out / 'closed-loop.png'}")


if __name__ == "__main__":
    main()
