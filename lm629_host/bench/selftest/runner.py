"""A selftest run and a compare: the options the bench is described by (:class:`Options`),
the reference model built from them (:func:`reference`), :func:`run` (the script on a chip,
whatever ends it) and :func:`compare` (a saved report replayed on today's model).

Why a module of its own: the order of the checks, the motor's safety around them and what a
failure becomes (FAIL with what was measured) are decided here, once, for the CLI and for
Python callers.
"""

from __future__ import annotations

import math
import platform
from collections.abc import Callable
from dataclasses import dataclass, field, replace

from lm629_host.chip.lm629 import LM629
from lm629_host.chip.safety import stop_on_error
from lm629_host.errors import LM629Error, ResetError
from lm629_host.transports import open_transport
from lm629_host.bench.selftest.checks import (
    INDEX_AT_REST,
    INDEX_PROBE_SAMPLES,
    check_busy,
    check_clock,
    check_core,
    hi_fault,
    check_motion,
    check_selects,
    variant_fault,
    index_at_rest,
)
from lm629_host.bench.selftest.lockstep import Lockstep
from lm629_host.bench.selftest.report import Fault, Measurement, Report

@dataclass
class Options:
    """What the selftest is told of the bench: the profile's chip and clock, its axes' chip
    selects, the encoder lines and the gains for ``motion``."""

    profile_hz: float
    chip: str = "lm629"
    selects: tuple[int, ...] = ()
    motion: bool = False
    lines: int = 500
    gains: dict[str, int] = field(default_factory=lambda: {"kp": 20})
    profile_path: str | None = None
    #: the shaft rests on the index (:func:`index_at_rest`): the model's is put under its
    #: shaft too
    index_at_rest: bool = False


def reference(options: Options) -> LM629:
    """A fresh chip model with the profile's chip and clock: what the chip is compared with
    (its index under the shaft when the chip's is, model choice 20's ``index_offset``)."""
    hz = round(options.profile_hz)
    url = f"sim://?chip={options.chip}&clock={hz}&lines={options.lines}"
    if options.index_at_rest:
        url += "&index_offset=0"
    return LM629(open_transport(url), chip=options.chip, clock_hz=hz)


def _versions() -> dict[str, str]:
    from importlib.metadata import PackageNotFoundError, version
    try:
        ours = version("lm629-host")
    except PackageNotFoundError:  # a checkout on sys.path
        ours = "unknown"
    return {"lm629_host": ours, "python": platform.python_version(),
            "platform": platform.platform()}


def run(chip: LM629, options: Options,
        progress: Callable[[str], None] = lambda _text: None) -> Report:
    """The selftest of ``chip`` (motor off unless ``options.motion``); never raises an
    :class:`~lm629_host.LM629Error`: a step that fails is the report's ``error`` (FAIL) with
    what was measured before it.  The chip is reset at the end."""
    report = Report(_versions(), {"url": chip.transport.url,
                                  "describe": chip.transport.describe()},
                    {"chip": options.chip, "clock_hz": options.profile_hz,
                     "cs": chip.chip_select, "lines": options.lines,
                     "path": options.profile_path}, options.motion,
                    busy_resolution_us=math.ceil(chip.transport.busy_probe_us))
    out: list[Measurement] = []
    model: LM629 | None = None
    # the core's and the clock's velocity runs drive nothing (gains 0): an axis's soft limits
    # (a profile's min/max) are lifted for them, and hold again for --motion's run
    limits, chip.limits = chip.limits, None
    try:
        # the core runs trajectories with the drive on (gains 0), --motion turns the motor:
        # whatever ends the script (an error, Ctrl-C) stops the motor first
        with stop_on_error(chip):
            rests = index_at_rest(chip)
            out.append(Measurement("wiring", INDEX_AT_REST, "RESET; SIP; "
                                   f"{INDEX_PROBE_SAMPLES} samples; RDSTAT", rests, rests,
                                   judged=False))
            model = reference(replace(options, index_at_rest=rests))
            ls = Lockstep(chip, model)
            ls.out = out
            progress("core: the chip and the model, command by command")
            stopped = check_core(ls)
            report.faults += [stopped] if stopped else []
            for fault in (hi_fault(ls), variant_fault(ls)):
                report.faults += [fault] if fault else []
            progress("clock: the sample period")
            fault = check_clock(ls, options.profile_hz)
            report.faults += [fault] if fault else []
            progress("busy: after each command byte")
            check_busy(ls)
            report.faults += check_selects(chip, options.selects or (chip.chip_select,), ls.out)
            chip.limits = limits
            if options.motion:
                progress("motion: the encoder and the index")
                report.faults += check_motion(ls, options.lines, options.gains)
            chip.reset()
    except ResetError as exc:
        report.error = str(exc)
        if exc.statuses and all(s == 0xFF for s in exc.statuses):
            report.faults.append(Fault(f"cs {chip.chip_select}", "no chip answers: every status "
                                       "read FF", "check the chip's /CS, power and clock"))
    except LM629Error as exc:
        report.error = f"{type(exc).__name__}: {exc}"
    finally:
        chip.limits = limits
        report.measurements = out
        if model is not None:
            model.close()
    return report


def compare(saved: Report) -> list[str]:
    """A saved report against today's model: the script replayed on a fresh model at the
    report's chip times.  Returns one line per value that differs (empty: no differences):
    a measurement whose chip value or expected value is not what today's model gives."""
    p = saved.profile
    rests = next((m.measured for m in saved.measurements if m.name == INDEX_AT_REST), False)
    options = Options(float(p["clock_hz"]), p["chip"], (), saved.motion, int(p["lines"] or 500),
                      index_at_rest=bool(rests))
    model = reference(options)
    ls = Lockstep(None, model, {m.name: m for m in saved.measurements})
    try:
        check_core(ls)
        check_clock(ls, options.profile_hz)
        check_busy(ls)
        if saved.motion:
            check_motion(ls, options.lines, options.gains)
    finally:
        model.close()
    today = {m.name: m for m in ls.out}
    lines = []
    for m in saved.measurements:
        now = today.get(m.name)
        if now is None or m.check == "wiring" and m.name.startswith("cs "):
            continue
        check = Measurement(m.check, m.name, m.command, m.measured, now.expected,
                            judged=m.judged, unit=m.unit)
        if m.expected != now.expected:
            lines.append(f"{m.name}: the report's model expected {m.show(m.expected)}, today's "
                         f"model gives {m.show(now.expected)} ({m.command})")
        if m.check == "busy":
            line = _busy_differs(m, now.expected, saved.busy_resolution_us)
            lines += [line] if line else []
        elif check.differs:
            lines.append(f"{m.name}: the chip read {m.show(m.measured)}, today's model gives "
                         f"{m.show(now.expected)} ({m.command})")
    return lines


def _busy_differs(m: Measurement, model_us: int | None, resolution: int | None) -> str | None:
    """A busy time that today's model's lies outside of, given the instrument's resolution
    (None: the report states none, a version 1 report: shown, not compared).  The probe
    read busy at a wait 1 us shorter than the one it read clear at, and its status read lands
    up to ``resolution`` us after the wait: the chip's busy time is in [measured - 1,
    measured + resolution]."""
    if m.measured is None or model_us is None or resolution is None:
        return None
    if m.measured - 1 <= model_us <= m.measured + resolution:
        return None
    return (f"{m.name}: the chip read {m.show(m.measured)} (its busy time {m.measured - 1} to "
            f"{m.measured + resolution} us, the instrument's resolution), today's model gives "
            f"{m.show(model_us)} ({m.command})")


__all__ = ["Options", "compare", "reference", "run"]
