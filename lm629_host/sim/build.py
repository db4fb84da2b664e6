"""A chip model configured from a simulator URL's options: the one place where ``sim://``,
``sim+emu://``, ``sim+avr://``, ``sim+ftdi://`` and ``lm629 sim serve`` turn ``?chip=lm628&
clock=6MHz&fault=busy...`` into a :class:`~lm629_host.sim.model.ChipModel`."""

from __future__ import annotations

import os

from lm629_host.errors import AxisError
from lm629_host.bus.opcodes import POSITION_MAX, POSITION_MIN
from lm629_host.urls import Option, dataclass_options, parse_options, query_params
from lm629_host.sim.model import ChipBus, ChipModel, ChipParams, MotorParams
from lm629_host.sim.vcd import NAMES as VCD_OPTIONS
from lm629_host.sim.wiring import wiring_of

_ALIASES = {"chip": "variant", "clock": "clock_hz"}

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

#: the URL options of the simulated chip: every field of ChipParams and MotorParams
_CHIP_OPTIONS = dataclass_options(ChipParams, [
    Option("clock_hz", "hz", unit="Hz"),  # the model checks the range
    Option("fault", "str", choices=tuple(f for f in FAULTS if f), optional=True),
    Option("reset_position", "int", lo=POSITION_MIN, hi=POSITION_MAX),
    Option("update_s", "float", lo=0.0, hi=1.0, unit="s")])
_MOTOR_OPTIONS = dataclass_options(MotorParams)


def build_model(url: str, *, allowed: frozenset[str] = frozenset()) -> ChipModel:
    """A :class:`ChipModel` configured from a simulator URL's query string.

    Used by every simulated transport (``sim://``, ``sim+avr://``, ``sim+ftdi://``), so that
    the same parameters mean the same thing everywhere.  Parameters in ``allowed`` belong to
    the calling transport and are skipped here; any other unknown name is an error.
    """
    chip, motor = ChipParams(), MotorParams()
    # strict_default(), unless the URL says strict= (below); never where wiring= miswires the
    # bench (sim/wiring.py): a bent wire bends the host's bytes, and the chip's protocol
    # checks would blame the host for the wire
    chip.strict = strict_default() and wiring_of(url) is None
    values = parse_options(url, _CHIP_OPTIONS + _MOTOR_OPTIONS, what="simulator",
                           ignore=allowed | {"wiring"} | VCD_OPTIONS, aliases=_ALIASES,
                           given_only=True)
    for name, value in values.items():
        if name == "clock_hz":
            value = round(value)
        elif name == "variant":
            value = value.lower()
        setattr(chip if hasattr(chip, name) else motor, name, value)
    return ChipModel(chip, motor)


#: the most chips a simulated bus takes (``axes=``)
MAX_AXES = 8


def axes_of(url: str, limit: int = MAX_AXES) -> int:
    """The URL's ``axes=`` (default 1), checked against ``limit`` chip selects."""
    raw = query_params(url).get("axes", "1")
    try:
        n = int(raw)
    except ValueError:
        raise ValueError(f"{url}: axes={raw!r} is not a whole number of chips") from None
    if n < 1:
        raise ValueError(f"{url}: axes={n}: a bus needs at least one chip")
    if n > limit:
        raise AxisError(n - 1, limit, f"the simulated adapter of {url}")
    return n


def build_bus(url: str, *, allowed: frozenset[str] = frozenset(),
              limit: int = MAX_AXES) -> ChipModel | ChipBus:
    """The chip (``axes=1``, the default) or the :class:`ChipBus` of ``axes=N`` chips, each
    with its own motor, all configured from the same URL parameters."""
    n = axes_of(url, limit)
    allowed = allowed | {"axes"}
    if n == 1:
        return build_model(url, allowed=allowed)
    return ChipBus([build_model(url, allowed=allowed) for _ in range(n)])
