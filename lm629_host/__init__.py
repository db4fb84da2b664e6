"""lm629_host: host driver, chip simulator and bench CLI for the LM628/LM629 motion controllers.

    import lm629_host
    with lm629_host.open("sim://") as chip:
        chip.reset()
        chip.load_filter(kp=20); chip.update_filter()
        chip.move_to(1000, velocity=65536, acceleration=655).wait()   # or MotionError

The names here (``__all__``) are what a lab script needs: opening a chip or a board, moves and
their results, the errors, the status flags, units, stopping, planning and tuning
(docs/python.md lists them).  Everything else lives in its module (``lm629_host.urls``,
``lm629_host.bus.program``...).  Each name is imported from its module on first use
(:data:`_HOMES`): ``import lm629_host`` loads almost nothing, a command line that opens no chip
(``lm629 sim serve``, ``lm629 calc``) loads no driver, and no script loads the tuner (the
largest module) before it calls :func:`autotune`; nothing here imports the simulator.
"""

import importlib as _importlib
import os as _os
import typing as _typing

from lm629_host.bus.program import DEFAULT_BUSY_TIMEOUT_S as _DEFAULT_BUSY_TIMEOUT_S

__version__ = "0.1.0"

if _typing.TYPE_CHECKING:  # every public name from its home, as type checkers and editors see it
    from lm629_host.bench.tuning import TuneResult, autotune
    from lm629_host.bus.opcodes import Cmd, FilterFlags, Signals, Status, TrajectoryFlags
    from lm629_host.bus.program import BusCycle, Program, ProgramResult
    from lm629_host.bus.snapshot import Snapshot
    from lm629_host.chip.lm629 import LM629
    from lm629_host.chip.move import Move, MoveResult, MoveRules
    from lm629_host.chip.safety import emergency_stop, stop_on_error
    from lm629_host.chip.shapes import Points, SCurve
    from lm629_host.chip.supervise import VelocityRun, run_velocity, search_index, wait_still
    from lm629_host.config.profile import Profile as _Profile
    from lm629_host.errors import (
        ArgumentError,
        AxisError,
        BusyTimeout,
        CommandError,
        FailsafeTripped,
        LM629Error,
        MotionError,
        MotionFault,
        ProtocolViolation,
        ResetError,
        SchemeError,
        TransportError,
        UpdateTooSoon,
        WaitTimeout,
    )
    from lm629_host.motion.board import Board, BoardMove, open_board
    from lm629_host.physics.linear import LinearPlan, plan_linear
    from lm629_host.physics.units import Scale
    from lm629_host.transports import DEFAULT_URL
    from lm629_host.urls import PortURL

#: module -> the public names it defines, each imported when first asked for
#: (``lm629_host.LM629``, ``from lm629_host import LM629``): a program loads only what it
#: uses, so that ``lm629 sim serve`` or ``lm629 calc`` load no driver and a ``socket://`` port
#: no simulator
_HOMES: dict[str, tuple[str, ...]] = {
    ".errors": ("ArgumentError", "AxisError", "BusyTimeout", "CommandError", "FailsafeTripped",
                "LM629Error", "MotionError", "MotionFault", "ProtocolViolation", "ResetError",
                "SchemeError", "TransportError", "UpdateTooSoon", "WaitTimeout"),
    ".chip.lm629": ("LM629",),
    ".bus.snapshot": ("Snapshot",),
    ".chip.move": ("Move", "MoveResult", "MoveRules"),
    ".chip.shapes": ("Points", "SCurve"),
    ".bus.opcodes": ("Cmd", "FilterFlags", "Signals", "Status", "TrajectoryFlags"),
    ".bus.program": ("BusCycle", "Program", "ProgramResult"),
    ".chip.safety": ("emergency_stop", "stop_on_error"),
    ".chip.supervise": ("VelocityRun", "run_velocity", "search_index", "wait_still"),
    ".transports": ("DEFAULT_URL",),
    ".physics.units": ("Scale",),
    ".motion.board": ("Board", "BoardMove", "open_board"),
    ".physics.linear": ("LinearPlan", "plan_linear"),
    ".bench.tuning": ("autotune", "TuneResult"),  # the largest module; most scripts never tune
}
#: name -> its module
_LAZY = {name: module for module, names in _HOMES.items() for name in names}


def __getattr__(name: str) -> _typing.Any:
    """A public name (:data:`_HOMES`): its module is imported when the name is first asked for.
    A submodule too (``lm629_host.urls.port_url`` after ``import lm629_host``, as when this
    package imported them all)."""
    if name in _LAZY:
        value = getattr(_importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    if not name.startswith("_"):
        try:
            return _importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":  # the submodule is there, an import in it failed
                raise
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})


def open(url: "str | PortURL | None" = None, *, chip: str | None = None,  # noqa: A001 - lm629_host.open, as io.open
         clock: float | str | None = None, trace=None,
         busy_timeout: float = _DEFAULT_BUSY_TIMEOUT_S,
         profile: "str | _os.PathLike[str] | _Profile | None" = None,
         apply: bool | str = "auto") -> "LM629":
    """Open the chip behind ``url`` (``sim://`` by default; see :mod:`lm629_host.transports`).

    ``chip`` is "lm628" or "lm629" and ``clock`` the chip's clock (Hz, or ``"6MHz"``); either
    may be said in the URL instead (``?chip=lm628&clock=6MHz``), and where both say it they
    must agree (:func:`lm629_host.transports.ports.resolve_port`).  ``trace`` is called with a
    :class:`BusCycle` for every bus cycle.  ``busy_timeout`` (s) bounds every busy check (0.2
    to 65.5 ms; default 5 ms).  On a multi-axis board ``?cs=k`` opens the chip on chip select
    ``k`` (default 0); :func:`open_board` opens them all.

    ``profile``: a bench profile (a path or a loaded one), as :func:`open_board` takes it: the
    port (when ``url`` is None), the chip and clock come from it, and the profile's axis on
    this chip select gives the chip its soft limits and its name (``chip.profile_axis``);
    ``apply`` says what is sent at open ("auto": the axis's settings when the chip has lost
    them, True: always, False: nothing).  A bad profile is a ProfileError (ValueError) before
    the port is opened.
    """
    from lm629_host.chip.lm629 import LM629
    from lm629_host.errors import ArgumentError
    from lm629_host.transports import DEFAULT_URL
    from lm629_host.transports.ports import profile_port, resolve_port

    prof = None
    if profile is not None:
        from lm629_host.config.profile import Profile, load_profile
        prof = profile if isinstance(profile, Profile) else load_profile(profile)
        if apply not in (True, False, "auto"):
            raise ArgumentError("apply", apply, f"apply={apply!r}: expected True, False or 'auto'")
        if url is None:
            url = profile_port(prof)
        chip = prof.chip if chip is None else chip
        clock = prof.clock_hz if clock is None else clock
    spec = resolve_port(DEFAULT_URL if url is None else url, chip=chip, clock=clock)
    transport = spec.open_transport(trace)
    try:
        opened = LM629(transport, chip=spec.chip, busy_timeout=busy_timeout, axis=spec.cs,
                       clock_hz=spec.clock_hz)
        if prof is not None:
            _with_profile(opened, prof, apply)
        return opened
    except BaseException:
        transport.close()
        raise


def _with_profile(chip: "LM629", prof: "_Profile", apply: bool | str) -> None:
    """The profile's axis on ``chip``'s chip select, if it has one: limits, variant and name
    (as :func:`open_board` gives each axis), then its settings as ``apply`` says."""
    import logging
    from dataclasses import replace

    from lm629_host.config.profile import apply_profile, attach, ensure_applied
    ax = prof.by_cs(chip.chip_select)
    if ax is None:
        return
    attach(chip, prof, ax)
    chip.move_rules = replace(chip.move_rules, clock_hz=prof.clock_hz)
    if apply == "auto":
        ensure_applied({ax.name: chip}, prof, logging.getLogger("lm629_host").warning)
    elif apply:
        apply_profile({ax.name: chip}, prof)


__all__ = [
    # opening a chip, a board
    "open", "open_board", "DEFAULT_URL", "LM629", "Board", "BoardMove",
    # moves
    "Move", "MoveResult", "MoveRules", "Snapshot", "plan_linear", "LinearPlan",
    # shaped moves (chip.move_profile)
    "SCurve", "Points",
    # velocity mode, the index, rest
    "run_velocity", "VelocityRun", "search_index", "wait_still",
    # errors
    "LM629Error", "ArgumentError", "AxisError", "SchemeError", "TransportError", "BusyTimeout",
    "ResetError", "CommandError", "WaitTimeout", "UpdateTooSoon", "MotionError", "MotionFault",
    "ProtocolViolation", "FailsafeTripped",
    # flags and commands
    "Status", "Signals", "FilterFlags", "TrajectoryFlags", "Cmd",
    # units, stopping, tuning
    "Scale", "emergency_stop", "stop_on_error", "autotune", "TuneResult",
    # bus programs, for experts and traces
    "Program", "ProgramResult", "BusCycle",
    "__version__",
]
