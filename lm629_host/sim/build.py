"""A chip model configured from a simulator URL's options: the one place where ``sim://``,
``sim+emu://``, ``sim+avr://``, ``sim+ftdi://`` and ``lm629 sim serve`` turn ``?chip=lm628&
clock=6MHz&fault=busy...`` into a :class:`~lm629_host.sim.model.ChipModel`."""

from __future__ import annotations

import os
from dataclasses import replace

from lm629_host.errors import AxisError
from lm629_host.bus.opcodes import BUSY_WORST_CASE_S, POSITION_MAX, POSITION_MIN, Cmd
from typing import Any

from lm629_host.bus.url_board import BOARD, BOARD_ROWS
from lm629_host.urls import Option, PortURL, dataclass_options, parse_options, query_params
from lm629_host.sim.model import ChipBus, ChipModel, ChipParams, MotorParams
from lm629_host.sim.usb import OPTIONS as USB_ROWS
from lm629_host.sim.vcd import OPTIONS as VCD_ROWS
from lm629_host.sim.wiring import OPTION as WIRING, board_lines_of

#: short names of the model's options (``busy=LTRJ:24.5``); the board's ``chip=`` and ``clock=``
#: are its rows (bus/url_board.py), and set the model's ``variant`` and ``clock_hz``
ALIASES = {"busy": "command_busy_s"}
_BOARD_TO_MODEL = {"chip": "variant", "clock": "clock_hz"}

#: the environment variable that makes every simulated chip strict unless its URL says
#: ``strict=0`` (docs/model.md): how a CI run of lab scripts, or any program that starts
#: simulators in other processes (``lm629 sim serve``, the CLI), asks for strictness once
STRICT_ENV = "LM629_SIM_STRICT"


def strict_default() -> bool:
    """Whether a simulated chip whose URL does not say ``strict=`` is strict: the one place
    that decides it (:data:`STRICT_ENV`, default no).  Every simulator is built here, and the
    transports that apply strictness themselves (``sim+ftdi://`` after each exchange, the AVR
    harness for bus timing) take it from the model they were given."""
    return os.environ.get(STRICT_ENV, "") not in ("", "0")

#: the bench failures the simulators rehearse: the chip never leaves reset, busy stuck high,
#: the /RST line not connected
FAULTS = (None, "reset", "busy", "rst")


def parse_command_busy(text: str) -> dict[int, float]:
    """``LTRJ:24.5,STT:31`` (microseconds after each command byte) -> {opcode: seconds}: the
    form ``lm629 selftest`` reports a chip's busy times in; ValueError naming the part."""
    out: dict[int, float] = {}
    for part in (p.strip() for p in text.split(",") if p.strip()):
        name, sep, us = part.partition(":")
        try:
            cmd = Cmd[name.strip().upper()]
        except KeyError:
            raise ValueError(f"{part!r}: {name.strip()!r} is not a command "
                             f"({', '.join(c.name for c in Cmd)})") from None
        try:
            value = float(us) if sep else float("nan")
        except ValueError:
            value = float("nan")
        if not 0 < value <= BUSY_WORST_CASE_S * 1e6:
            raise ValueError(f"{part!r}: give COMMAND:MICROSECONDS, the busy time 0 < us <= "
                             f"{BUSY_WORST_CASE_S * 1e6:g} (the datasheet's worst case)")
        out[int(cmd)] = value * 1e-6
    return out


#: the URL options of the simulated chip: every field of ChipParams and MotorParams
_CHIP_OPTIONS = dataclass_options(ChipParams, [
    Option("command_busy_s", "str", parse=parse_command_busy, unit="CMD:us,..."),
    Option("clock_hz", "hz", unit="Hz"),  # the model checks the range
    Option("fault", "str", choices=tuple(f for f in FAULTS if f), optional=True),
    Option("reset_position", "int", lo=POSITION_MIN, hi=POSITION_MAX),
    Option("update_s", "float", lo=0.0, hi=1.0, unit="s")])
_MOTOR_OPTIONS = dataclass_options(MotorParams)
_MODEL_NAMES = frozenset(o.name for o in (*_CHIP_OPTIONS, *_MOTOR_OPTIONS))
#: the model's rows of a simulator's table
MODEL_ROWS = (*_CHIP_OPTIONS, *_MOTOR_OPTIONS)
#: the options that build a twin of a bench from its profile (:func:`build_bus`)
TWIN_ROWS = (Option("profile", "str"), Option("axis", "str"))
TWIN_OPTIONS = frozenset(o.name for o in TWIN_ROWS)
#: every simulator's rows (a transport's table: the board's, then its own, then these)
SIM_ROWS = (*MODEL_ROWS, *TWIN_ROWS, *VCD_ROWS, WIRING)
#: the table of a bare simulator URL (``sim://``)
SIM_OPTIONS = (*BOARD_ROWS, *SIM_ROWS)
#: the table of a served far end's URL (``lm629 sim serve``): a simulator's and the USB
#: adapter's in front of the bridge
SERVED_OPTIONS = (*BOARD_ROWS, *USB_ROWS, *SIM_ROWS)


def sim_options(url: str | PortURL, table: tuple[Option, ...] = SIM_OPTIONS, *,
                defaults: bool = False) -> dict[str, Any]:
    """The options ``url`` gives (with ``defaults``, every row's), checked against ``table``
    (a simulated transport's whole table): the one parse of its URL, handed to
    :func:`build_bus`."""
    return parse_options(url, table, what="simulator", aliases=ALIASES,
                         given_only=not defaults)


def build_model(url: str | PortURL, options: dict[str, Any] | None = None) -> ChipModel:
    """A :class:`ChipModel` configured from a simulator URL's options.

    Used by every simulated transport (``sim://``, ``sim+avr://``, ``sim+ftdi://``), so that
    the same parameters mean the same thing everywhere.  ``options``: the URL parsed by the
    transport against its whole table (:func:`sim_options`); None: ``url`` is a bare
    simulator's, parsed here against :data:`SIM_OPTIONS`.
    """
    if options is None:
        options = sim_options(url)
    chip, motor = ChipParams(), MotorParams()
    # strict_default(), unless the URL says strict= (below); never where wiring= miswires the
    # bench (sim/wiring.py): a bent wire bends the host's bytes, and the chip's protocol
    # checks would blame the host for the wire
    bend, board_lines = options.get("wiring") or (None, frozenset())
    chip.strict = strict_default() and bend is None
    said = {ALIASES.get(k, k) for k in query_params(url)}  # a table with defaults: the given
    values = {_BOARD_TO_MODEL.get(k, k): v for k, v in options.items()
              if k in said and (k in _MODEL_NAMES or k in _BOARD_TO_MODEL)}
    for name, value in values.items():
        if name == "clock_hz":
            value = round(value)
        elif name == "variant":
            value = value.lower()
        setattr(chip if hasattr(chip, name) else motor, name, value)
    for name, value in board_lines_of(board_lines).items():  # wiring=hi-open, ...
        setattr(chip if hasattr(chip, name) else motor, name, value)
    return ChipModel(chip, motor)


#: the most chips a simulated bus takes (``axes=``)
MAX_AXES = 8


def axes_of(url: str | PortURL, limit: int = MAX_AXES) -> int:
    """The URL's ``axes=`` (default 1), checked against ``limit`` chip selects."""
    raw = query_params(url).get("axes")
    n = 1 if raw is None else BOARD["axes"].convert(raw, url)  # the board's row: one rule
    if n > limit:
        raise AxisError(n - 1, limit, f"the simulated adapter of {url}")
    return n


#: the motor parameters that set how the shaft moves: a URL that names one gives its own
#: motor, a bench of its own, and the profile's plants are not used (the faults and the
#: encoder, ``stall=``, ``reversed=``, ``lines=``..., apply to a twin as to any motor)
DYNAMICS = frozenset({"amp_volts", "resistance", "torque_constant", "inertia", "friction",
                      "coulomb", "load_torque", "accel", "tau", "dry", "load"})


def build_bus(url: str | PortURL, options: dict[str, Any] | None = None, *,
              limit: int = MAX_AXES) -> ChipModel | ChipBus:
    """The chip (``axes=1``, the default) or the :class:`ChipBus` of ``axes=N`` chips, each
    with its own motor, all configured from the same URL parameters.

    ``profile=FILE``: a twin of the bench the profile describes: a chip per chip select its
    axes use (or ``axes=``, when more), each axis's motor built from its
    ``[axis.NAME.plant]`` (the other motors the URL's), its chip, lines and the board's clock
    unless the URL says them; ``axis=NAME``: that axis's chip alone (one chip).  A URL that
    names a parameter of the motor's dynamics (:data:`DYNAMICS`) keeps its own motor: the
    profile then gives only the chips, lines and clock (``--profile FILE --port
    'sim://?inertia=4e-5'`` is a bench of its own, with the profile's axes)."""
    if options is None:
        options = sim_options(url)
    q = query_params(url)
    if "profile" in q:
        return _twin(url, q["profile"], q.get("axis"), options, limit)
    if "axis" in q:
        raise ValueError(f"{url}: axis= names an axis of a profile: give profile=FILE too")
    n = axes_of(url, limit)
    if n == 1:
        return build_model(url, options)
    return ChipBus([build_model(url, options) for _ in range(n)])


def _twin(url: str | PortURL, path: str, axis: str | None, options: dict[str, Any],
          limit: int) -> ChipModel | ChipBus:
    from lm629_host.config.profile import PLANT_KEYS, load_profile
    prof = load_profile(path)
    if axis is not None:
        axes = {0: prof.axis(axis)}  # ValueError naming the axes it has
        if "axes" in query_params(url) and axes_of(url, limit) != 1:
            raise ValueError(f"{url}: axis={axis} builds one chip: axes= must be 1")
    else:
        axes = {a.cs: a for a in prof.axes.values()}
    n = max(axes, default=0) + 1
    if "axes" in query_params(url):
        # the bench the URL names: fewer chips than the profile's axes is a bench with only
        # those wired (``--axis x`` on a one-chip bench), and only they are built
        n = axes_of(url, limit)
    if n > limit:
        raise AxisError(n - 1, limit, f"the simulated adapter of {url} ({path})")
    said = {ALIASES.get(k, _BOARD_TO_MODEL.get(k, k)) for k in query_params(url)}
    chips = []
    for cs in range(n):
        model = build_model(url, options)
        ax = axes.get(cs)
        if ax is not None:
            if "variant" not in said:
                model.params.variant = ax.chip
            if "clock_hz" not in said:
                model.params.clock_hz = round(prof.clock_hz)
            plant = {} if said & DYNAMICS else (ax.plant or {})
            motor = {k: v for k, v in plant.items()
                     if k in PLANT_KEYS and hasattr(model.motor_params, k) and k not in said}
            if ax.lines is not None and "lines" not in said:
                motor["lines"] = ax.lines
            model = ChipModel(model.params, replace(model.motor_params, **motor))
        chips.append(model)
    return chips[0] if n == 1 else ChipBus(chips)
