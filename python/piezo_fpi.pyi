"""Piezo nanopositioning stages from Python: the FPI board over its command link,
and the FPI-FFEM method's calibration, prediction and inversion.

A thin binding over the Rust host tools (`fpi`): every command and computation is
the host library's. Units: lengths in µm, voltages in V, forces in N, times in s,
frequencies in Hz, unless a name says otherwise (``_ms``, ``_um`` …).
"""

from os import PathLike
from typing import Any, Dict, List, Literal, Optional, Sequence, Tuple, TypedDict, Union, final, overload

import numpy as np
import numpy.typing as npt

__all__ = [
    "__version__",
    "BoardError",
    "LinkError",
    "Interrupted",
    "Board",
    "Recorder",
    "Settings",
    "Emulator",
    "Model",
    "calibrate",
    "predict_axes",
    "refine_axes",
    "qemu_available",
]

__version__: str

_ArrayLike = Union[Sequence[float], npt.NDArray[np.float64]]
_Columns = Dict[str, npt.NDArray[np.float64]]
_Path = Union[str, PathLike]

class _Recorded(TypedDict):
    """A motion recorded at every tick (``move``/``wave`` with ``record=True``)."""

    tick: int
    """The tick the board took the command on (the recording's first)."""
    recording: _Columns
    """Every tick, as ``Board.record``'s columns."""

class BoardError(Exception):
    """The board refused a command, or took it and faulted on it."""

    reason: str
    """The board's reason, e.g. ``target 45.000 µm outside the stroke 0.000–39.921 µm``."""
    code: str
    """The refusal's kind (``Range``, ``State`` …), or ``Fault``."""

class LinkError(ConnectionError):
    """The link to the board could not be opened, is closed, or the board stopped answering."""

class Interrupted(KeyboardInterrupt):
    """Ctrl-C stopped ``Board.record`` or ``Board.stream``; the board was left in order."""

    done: Any
    """What was done: the partial recording (a dict of arrays), or ``points`` and
    ``held_at_tick`` of a stream."""

def qemu_available() -> bool:
    """Whether ``qemu-system-arm`` is there to run the emulated board."""

@final
class Emulator:
    """The emulated board (``fpi board emulate``): the firmware on QEMU's
    netduinoplus2, its link on a TCP port. Runs the ELF ``firmware``, else builds
    the firmware with cargo in the source tree the package was built from (an
    installed package without that tree needs ``firmware``). A context manager;
    ``close()`` stops QEMU."""

    def __new__(
        cls,
        listen: Optional[str] = None,
        link: str = "usb",
        frontend: str = "internal",
        firmware: Optional[Union[str, PathLike[str]]] = None,
        axes: int = 1,
    ) -> "Emulator":
        """``listen``: ``HOST:PORT`` (default: a free loopback port); ``link``: the
        link whose rate the board paces its own at, ``"usb"`` (800 kB/s) or
        ``"uart"`` (11 520 B/s); ``frontend``: the analog front end the board
        converts with, ``"internal"`` or ``"precision"``; ``firmware``: the
        emulated board's firmware ELF (``cargo build --profile firmware --target
        thumbv7em-none-eabihf -p fpi-firmware --bin fpi-firmware --features
        qemu``), as ``fpi board emulate --firmware``; ``axes``: 1, or 2 (the XY
        stage as designed; internal front end only), as ``--axes``."""
    @property
    def port(self) -> str:
        """``tcp:HOST:PORT``: what ``Board`` opens."""
    def output(self) -> str:
        """What the firmware and QEMU printed so far."""
    def close(self) -> None: ...
    def __enter__(self) -> "Emulator": ...
    def __exit__(self, *exc: object) -> bool: ...

@final
class Board:
    """A board over its command link: one method per ``fpi board`` command.

    Refusals and faults raise ``BoardError`` (with the board's ``reason``), bad
    arguments ``ValueError``/``TypeError`` naming the argument, a failed link
    ``LinkError``. Motion methods return the control tick the board took them on.
    A context manager; ``close()`` closes the link.
    """

    def __new__(cls, port: str) -> "Board":
        """``port``: a serial device (``/dev/ttyUSB0``, ``COM3``), ``tcp:HOST:PORT``
        (the emulated board) or ``virtual`` (the firmware built for this host, run
        in this process at real time, starting afresh; its link paced as the UART,
        or as USB with ``virtual:usb``; ``virtual:xy``, ``virtual:usb:xyz-built``…
        a board of several axes on that stage)."""
    @property
    def port(self) -> str: ...
    @property
    def axis(self) -> str:
        """The axis its per-axis calls address: ``"x"``, ``"y"`` or ``"z"``."""
    @property
    def axes(self) -> Dict[str, "Board"]:
        """Each axis of the board by name: the same board on the same link, its
        per-axis calls addressing that axis (``board.axes["y"].step(20.0)``). A
        board of one axis has ``"x"`` only."""
    @property
    def settings(self) -> "Settings":
        """The board's runtime settings by key path, a mapping:
        ``board.settings["stage/0/damping"] = False``."""
    @property
    def rate_hz(self) -> float:
        """The control rate, Hz."""
    @property
    def closed(self) -> bool: ...
    def info(self) -> Dict[str, Any]:
        """What the board has (``fpi board info``): ``board`` (``driver``,
        ``emulated`` or ``virtual``), ``firmware``, ``protocol``, ``axes``,
        ``front_end`` (``internal`` or ``precision``), ``rate_hz``,
        ``capacity``, ``buffers``, ``limits`` (``setpoint_min_V``,
        ``setpoint_max_V``, ``step_max_V``, ``safe_min_V``, ``safe_max_V``),
        ``reset``, ``link`` (``usb`` or ``uart``), ``link_bytes_per_s``,
        ``features`` (``closed_loop``, ``dynamics``, ``damping``, ``shaping``,
        ``mass_ratio``, ``bench``: each True or False), ``commands`` (the link
        commands it takes) and ``settings`` (the runtime settings' keys it
        has)."""
    def status(self) -> Dict[str, Any]:
        """The state (``fpi board status``): ``state`` (running, parked, fault),
        ``fault``, ``reference_um``, ``estimate_um``, ``position_sensor_um``,
        ``setpoint_V``, ``force_N``, ``amplifier_on``, ``source``, ``loop``,
        ``damping``, ``shaping``, ``lead_ratio`` and ``lead_applied`` (the
        explained force's learned ratio: the stage's mass over the tuned one's
        where applied, else the fit's ratio that autotune stores as
        ``damping.lead_baseline``; ``None`` where the model has no lead),
        ``model`` (``crc``, ``origin``, ``stroke_um``, ``feedback`` …), ``stream``,
        ``recorder``, ``link`` …; ``axis`` (the axis it describes) and
        ``fault_axis`` (the axis whose fault parked every axis, or ``None``)."""
    def status_text(self) -> str:
        """What ``fpi board status`` prints."""
    def position(self) -> float:
        """Position, µm: the position sensor when the model closes a loop on it,
        else the model's estimate (PI: ``POS?``)."""
    def on_target(self, tolerance_um: float = ...) -> bool:
        """(``tolerance_um``: 0.1 by default.) Running, the reference held, the position within ``tolerance_um`` of it (PI: ``ONT?``)."""
    def wait_on_target(self, timeout: float = 5.0, tolerance_um: float = ...) -> float:
        """Waits up to ``timeout`` s until on target; the position, µm. ``TimeoutError`` otherwise."""
    @overload
    def move(
        self,
        target_um: Optional[float] = None,
        speed: float = 1000.0,
        *,
        record: Literal[False] = False,
        x: Optional[float] = None,
        y: Optional[float] = None,
        z: Optional[float] = None,
    ) -> int:
        """Ramps to ``target_um`` at ``speed`` µm/s and holds it (PI: ``MOV``); the tick it started.
        On a board of several axes, ``move(x=10.0, y=20.0)`` moves each axis named
        from the same tick."""
    @overload
    def move(
        self,
        target_um: Optional[float] = None,
        speed: float = 1000.0,
        *,
        record: Literal[True],
        x: Optional[float] = None,
        y: Optional[float] = None,
        z: Optional[float] = None,
    ) -> _Recorded:
        """The move, recorded at every tick (every column of ``record``, ``x_fhps_um``
        the true position on the emulated board) until it holds the target and 50 ms
        more: ``tick`` and ``recording``. A fault meanwhile: ``BoardError``. Ctrl-C:
        ``Interrupted`` with the recording so far (the move goes on)."""
    @overload
    def wave(
        self,
        shape: str = "sine",
        *,
        amplitude_um: float,
        offset_um: float,
        freq_hz: float,
        cycles: int = 0,
        record: Literal[False] = False,
    ) -> int:
        """The waveform generator (PI: ``WAV`` + ``WGO``): ``sine``, ``triangle`` or
        ``cosine``; half-swing ``amplitude_um`` about ``offset_um``; ``cycles`` 0 runs
        until the next command."""
    @overload
    def wave(
        self,
        shape: str = "sine",
        *,
        amplitude_um: float,
        offset_um: float,
        freq_hz: float,
        cycles: int = 0,
        record: Literal[True],
        seconds: Optional[float] = None,
    ) -> _Recorded:
        """The wave, recorded at every tick from its approach for ``seconds`` (needed
        where ``cycles`` is 0), or until a finite wave has ended and 50 ms more:
        ``tick`` and ``recording``, as ``move(record=True)``."""
    def stream(
        self, points_um: _ArrayLike, interval: int = 20, *, record: bool = False
    ) -> Dict[str, Any]:
        """Streams a trajectory (µm), one point every ``interval`` control ticks;
        ``points``, ``started_tick`` (for a stream ``armed`` for the trigger
        input: the tick it was armed), ``armed``, ``underrun_ticks`` (and with
        ``record`` the
        ``recording`` of every tick until the board holds the last point, and 50 ms
        more). Ctrl-C: ``Interrupted``, board holding."""
    def record(self, seconds: float, decimation: int = 20) -> _Columns:
        """The data recorder (PI: ``DRC``/``DRR?``): every ``decimation``-th tick for
        ``seconds`` of board time, as the recording's CSV columns (``t_s``,
        ``voltage_V``, ``force_N``, ``x_ref_um``, ``x_est_um``, ``status``,
        ``x_fhps_um``, ``x_sensor_um``). Ctrl-C: ``Interrupted`` with the partial recording."""
    def record_start(
        self,
        *,
        decimation: int = 1,
        signals: Optional[Sequence[str]] = None,
        keep: bool = True,
    ) -> Recorder:
        """A live recording (PI: ``DRC``, then ``DRR?`` while motions run): the recorder
        armed for every ``decimation``-th tick and read by a thread of its own between
        this board's other commands. ``signals``: the columns to record (every one by
        default). ``keep=False``: ``stop()`` gives only what ``read()`` had not taken.
        ``ValueError`` for a decimation the link cannot carry; ``BoardError`` if one runs
        already."""
    def load(
        self,
        model: _Path,
        fem: Optional[_Path] = None,
        *,
        store: bool = False,
        match_mass: bool = False,
        rate: int = 20000,
        u_max: float = 150.0,
        slew: float = 100.0,
        stroke_voltage: Optional[float] = None,
    ) -> Dict[str, Any]:
        """Uploads a calibrated model (with the stage's FEM table ``fem``) or a
        firmware model file; the stage must be parked. ``crc``, ``bytes``, ``tick``
        (a file of several axes, ``fpi board load`` of it: every axis's model and the
        decoupling of its coupling; ``axes`` and each axis's ``tick``);
        ``match_mass`` then measures the stage's mode and starts the learned mass
        ratio there (``stage_mode_hz``, ``mass_ratio``)."""
    def factory(self) -> int:
        """Forgets the stored model and runs the factory default."""
    def safe(self) -> int:
        """Parks the stage: ramps to the safe voltage, amplifier off."""
    def clear_fault(self) -> int:
        """Clears a latched fault (the stage stays parked)."""
    def hold(self) -> int:
        """Stops the reference where it is (PI: ``HLT``)."""
    def analog(self) -> int:
        """Follows the analog reference input (0–3.3 V over the stroke)."""
    def drive(self, mode: str) -> int:
        """``compensated`` (inverse FPI) or ``uncompensated`` (straight line)."""
    def loop(self, mode: str) -> int:
        """``open``, ``closed`` or ``feedback``, without a jump (PI: ``SVO``)."""
    def damping(self, on: Union[bool, str]) -> int:
        """The model's active damping on or off."""
    def shaping(self, on: Union[bool, str]) -> int:
        """The model's reference shaping on or off."""
    def trigger(
        self,
        mode: str,
        *,
        step_um: Optional[float] = None,
        band_um: Optional[float] = None,
        low_um: Optional[float] = None,
        high_um: Optional[float] = None,
        pulse_ticks: Optional[int] = None,
    ) -> int:
        """The trigger output: ``off``, ``travel``, ``on_target``, ``window`` or ``point``
        (PI: ``CTO``); levels not given stay as the board has them."""
    def trigger_in(self, starts: str) -> int:
        """What the trigger input's rising edge starts: ``off``, ``motion``, ``recorder``
        or ``both`` (PI: ``CTI``/``WGO`` start at trigger)."""
    def supervise(self, ms: int) -> int:
        """Parks the stage if the host is silent ``ms`` ms while it drives it (0: off)."""
    def reset(self) -> Dict[str, Any]:
        """Resets the board (it starts parked); its new ``info()``."""
    def bench(
        self,
        *,
        analog_v: Optional[float] = None,
        sensor: Optional[str] = None,
        force_offset_n: Optional[float] = None,
        stall_ticks: Optional[int] = None,
        damage_stored: bool = False,
        position_sensor: Optional[str] = None,
        stage: Optional[str] = None,
        trigger_in_ticks: Optional[int] = None,
    ) -> List[str]:
        """The emulated board's virtual bench (a real board refuses); what was set."""
    def raster(
        self,
        fast: str,
        slow: str,
        *,
        freq_hz: float,
        lines: int,
        from_um: float,
        to_um: float,
        slow_from_um: Optional[float] = None,
        slow_to_um: Optional[float] = None,
        staircase: bool = False,
    ) -> Dict[str, Any]:
        """A raster on two axes of a board of several (``fpi board raster``):
        axis ``fast`` a triangle at ``freq_hz``, axis ``slow`` a ramp (or a
        ``staircase``), the lines started on the same tick, every axis
        recorded. ``fast_rms_pct`` and ``slow_rms_pct`` (the RMS error over the
        central 80 % of each line, % of the fast axis's span), ``on_truth``,
        ``missing``, and under each axis's name its recording (a dict of
        arrays)."""
    def step(
        self,
        from_um: float,
        to_um: float,
        *,
        seconds: float = 0.05,
        tol_um: Optional[float] = None,
        duration_ms: float = 1.5,
        decimation: int = 1,
    ) -> Dict[str, Any]:
        """A scored step: ``rise_ms``, ``overshoot_um``, ``settle_ms``,
        ``settle_tol_ms``, ``final_error_um``, ``governed_ticks``, ``recording``. A failure parks the
        board with its loop mode, damping and shaping as they were."""
    def frf(
        self,
        *,
        from_hz: float = 20.0,
        to_hz: float = 4000.0,
        points: int = 40,
        amplitude_um: float = 0.1,
        at_um: float = 20.0,
        zoom_points: int = 12,
    ) -> Dict[str, npt.NDArray[Any]]:
        """The frequency response: ``f_hz`` and complex ``x`` (µm/µm), ``force``
        (N/µm), ``dynamic`` (N/µm), ``x_per_v`` (µm/V)."""
    def autotune(
        self,
        model: _Path,
        out: _Path,
        fem: Optional[_Path] = None,
        *,
        trials: int = ...,
        store: bool = False,
        rate: int = 20000,
        u_max: float = 150.0,
        slew: float = 100.0,
        stroke_voltage: Optional[float] = None,
        damping: bool = True,
        target_damping: float = 0.5,
        force_noise_n: Optional[float] = None,
        max_sensitivity: float = 1.6,
        bandwidth_hz: Optional[float] = None,
        every_axis: bool = False,
        sensor_crosstalk: float = 0.0,
    ) -> str:
        """``fpi board autotune`` (``every_axis=True``: of every axis of a board of
        several, then their coupling, into one file of several axes that ``load``
        loads whole; ``sensor_crosstalk``: the sensors' calibration; ``trials``: ``--trials``, 2 by default, the feedforward's
        refinement through the board; ``damping=False``: ``--no-damping``;
        ``target_damping``, ``force_noise_n`` (the force sensor's σ, N, designed
        for instead of the one measured), ``max_sensitivity``, ``bandwidth_hz``:
        the flags of the same names); writes the tuned model to ``out``; its
        table. ``out`` is checked before the board is measured, and written
        before the tuned model runs for good; a failure once the board was
        changed puts it back (parked, the model, loop mode, damping and shaping
        it ran)."""
    def close(self) -> None: ...
    def __enter__(self) -> "Board": ...
    def __exit__(self, *exc: object) -> bool: ...

@final
class Recorder:
    """A live recording (``Board.record_start``): ``read()`` what came since the last
    read, ``stop()`` the whole recording, both as ``Board.record``'s columns. Losses
    are counted (``gaps``, ``missing``, ``dropped``) and warned of, never silent."""

    def read(self) -> _Columns:
        """What came since the last read (empty arrays where nothing did)."""
    def stop(self) -> _Columns:
        """Stops the recorder: the whole recording (``BoardError`` if stopped already)."""
    @property
    def running(self) -> bool:
        """It still records."""
    @property
    def start_tick(self) -> Optional[int]:
        """The tick the board took the recording's start on."""
    @property
    def samples(self) -> int:
        """Samples received so far."""
    @property
    def gaps(self) -> int:
        """Places where a sample did not follow the one before by the decimation."""
    @property
    def missing(self) -> int:
        """Samples the gaps miss."""
    @property
    def dropped(self) -> int:
        """Samples the board's ring dropped."""
    def __enter__(self) -> Recorder: ...
    def __exit__(self, *exc: object) -> bool: ...

@final
class Settings:
    """The board's runtime settings by key path (the book's reference lists
    them): ``settings[key]`` reads one, ``settings[key] = value`` changes it as
    its named method would, with the board's checks (a refusal raises
    ``BoardError``). Keys use slashes or dots (``"stage/0/loop_mode"``,
    ``"stage.0.loop_mode"``); a key that is no setting raises ``KeyError``.
    Values are JSON's: ``bool``, ``int``, ``str`` (``"closed"``)."""

    def __getitem__(self, key: str, /) -> Any: ...
    def __setitem__(self, key: str, value: Any, /) -> None: ...
    def __contains__(self, key: str, /) -> bool: ...
    def __len__(self) -> int: ...
    def __iter__(self) -> Any: ...
    def keys(self) -> List[str]:
        """Every key, in the tree's order."""
    def to_dict(self) -> Dict[str, Any]:
        """Every setting's value (``None`` where the running model has no such section)."""
    def describe(self, key: str) -> Dict[str, Optional[str]]:
        """The declaration: ``doc``, ``range``, ``unit``, ``default``."""

@final
class Model:
    """A calibrated model (``fpi calibrate``'s file)."""

    @staticmethod
    def load(path: _Path) -> "Model": ...
    def save(self, path: _Path) -> None: ...
    @property
    def kind(self) -> str: ...
    @property
    def rmse_um(self) -> float:
        """RMSE of the fit, µm."""
    @property
    def mte_um(self) -> float:
        """Largest error of the fit, µm."""
    @property
    def per_file(self) -> List[Dict[str, Any]]: ...
    @property
    def warnings(self) -> List[str]: ...
    @property
    def fem_correction(self) -> Optional[Dict[str, Any]]:
        """The correction of the stage's FEM tables (``fpi refine``, ``fpi axes
        refine``): ``stage_gain``, ``stage_offset_um``, ``preload_scale``, ``fem``,
        ``refined_on``; ``None`` without one."""
    def predict(self, *, fem: _Path, t_s: _ArrayLike, voltage_V: _ArrayLike) -> _Columns:
        """``fpi predict``: ``t_s``, ``voltage_V``, ``x_pea_um``, ``preload_N``, ``x_fhps_um``."""
    def refine(
        self,
        *,
        fem: _Path,
        runs: Sequence[Dict[str, _ArrayLike]],
        names: Optional[Sequence[str]] = None,
    ) -> "Model":
        """``fpi refine``: the model with the correction of the FEM table ``fem``
        estimated from measured runs of the built stage (``t_s``, ``voltage_V``,
        ``force_N``, ``x_fhps_um``)."""
    def invert(
        self, *, fem: _Path, t_s: _ArrayLike, x_fhps_um: _ArrayLike, u_max: float = 150.0
    ) -> _Columns:
        """``fpi invert``: ``t_s``, ``voltage_V`` (V) that make the stage follow ``x_fhps_um``."""

def predict_axes(
    models: Sequence[Model],
    *,
    grid: _Path,
    t_s: _ArrayLike,
    voltages: Sequence[_ArrayLike],
    independent: bool = False,
) -> _Columns:
    """``fpi axes predict``: every axis of a stage of several stacks from its FEM
    grid, ``models`` one for every stack or one per stack (a model refined by
    ``fpi axes refine`` brings its axis's correction of the grid); ``t_s`` and
    per axis ``voltage_V@x``, ``x_pea_um@x``, ``preload_N@x``, ``x_fhps_um@x``,
    …."""

def refine_axes(
    models: Sequence[Model],
    *,
    grid: _Path,
    runs: Sequence[Dict[str, _ArrayLike]],
    names: Optional[Sequence[str]] = None,
) -> List[Model]:
    """``fpi axes refine``: the grid corrected for the built stage axis by axis
    from measured ``runs`` (``t_s`` and per axis ``voltage_V@x``, ``force_N@x``,
    ``x_fhps_um@x``); each stack's model with its axis's correction, in axis
    order (``predict_axes`` applies it)."""

def calibrate(
    runs: Sequence[Dict[str, _ArrayLike]],
    kind: Optional[str] = None,
    *,
    operators: Optional[int] = None,
    compliance: Optional[float] = None,
    rows: Optional[Tuple[int, int]] = None,
    names: Optional[Sequence[str]] = None,
) -> Model:
    """``fpi calibrate`` on recordings given as dicts of arrays (``t_s``,
    ``voltage_V``, ``force_N``, ``displacement_um`` or ``x_fhps_um``; a board
    recording works as it is)."""
