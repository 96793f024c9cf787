"""Fixtures of the piezo_fpi tests: the boards (the in-process `virtual` board,
and the emulated board on QEMU when qemu-system-arm is there, else a loud skip
notice; under CI=true its absence fails), the datasets, and the `fpi` CLI the
method's numbers are checked against."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import piezo_fpi as pf

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests-host" / "data"


def under_ci() -> bool:
    v = os.environ.get("CI", "")
    return v not in ("", "false", "0")


def loud_skip(what: str, why: str) -> None:
    """Skips with a notice on the process's own stderr (pytest captures the
    test's), so a run without the emulated board is not taken for one with it."""
    notice = f"\n!!!!! SKIPPED {what}: {why}\n"
    sys.__stderr__.write(notice)
    sys.__stderr__.flush()
    pytest.skip(why)


def read_csv(path) -> dict:
    """A dataset (CSV, .gz allowed) as a dict of float arrays by column."""
    a = np.genfromtxt(path, delimiter=",", names=True, dtype=np.float64, encoding="utf-8")
    return {name: np.asarray(a[name], dtype=np.float64) for name in a.dtype.names}


def fpi_command() -> list:
    """The `fpi` CLI: $FPI_BIN (the Rust test that runs these sets it), else
    `cargo run` in the source tree."""
    exe = os.environ.get("FPI_BIN")
    if exe:
        return [exe]
    if shutil.which("cargo") is None:
        loud_skip("the CLI comparisons", "neither FPI_BIN nor cargo is there to run `fpi`")
    return ["cargo", "run", "-q", "--manifest-path", str(ROOT / "Cargo.toml"), "-p", "fpi-host", "--bin", "fpi", "--"]


@pytest.fixture(scope="session")
def fpi():
    """Runs `fpi ARGS…` (from the project's root); its stdout."""
    base = fpi_command()

    def run(*args):
        r = subprocess.run(base + [str(a) for a in args], cwd=ROOT, capture_output=True, text=True)
        assert r.returncode == 0, f"fpi {' '.join(map(str, args))} failed:\n{r.stderr}"
        return r.stdout

    return run


@pytest.fixture(scope="session")
def emulator():
    """The emulated board (QEMU), one for the session."""
    if not pf.qemu_available():
        why = "qemu-system-arm is not installed (install it, or set QEMU_SYSTEM_ARM)"
        if under_ci():
            pytest.fail(f"CI must run the emulated board: {why}")
        loud_skip("the piezo_fpi tests on the emulated board", why)
    with pf.Emulator() as e:
        yield e


@pytest.fixture(params=["virtual", "emulated"])
def board(request):
    """A fresh board of each kind: the in-process board, and the emulated board
    reset between tests (it starts parked with the factory model)."""
    if request.param == "virtual":
        with pf.Board("virtual") as b:
            yield b
    else:
        e = request.getfixturevalue("emulator")
        with pf.Board(e.port) as b:
            b.reset()
            b.factory()
            yield b
