"""``lm629 selftest``: is this chip and this board what the profile says, and where does the
model differ from silicon (docs/selftest.md says what each check proves).

Why: everything the project knows about the LM629 comes from documents and a model.  A bench
whose crystal is not the profile's makes every velocity and time wrong without an error; an HI
or index line that is not wired makes interrupts and homing wait for ever.  The selftest runs a
fixed script, motor off unless ``motion``:

* **core**: the same command sequence on the chip and, in lockstep, on a fresh chip model
  (a ``sim://`` transport with the profile's chip and clock); every read is compared.  Reads
  that change with time are taken at a known *chip* time: the desired position of a slow
  velocity-mode or cruising run (filter gains 0, so nothing drives the motor) is the chip's
  own clock, so the model is run to the same desired position before its reads, and a late
  host makes no false difference;
* **clock**: the sample period against the transport's clock (the bridge's timer stamps of a
  recording, the simulated clock, the host's clock on an FT232H), over :data:`CLOCK_RUN_S`:
  the median of many slopes, so that a paused host moves no figure;
* **wiring**: HI seen on a breakpoint interrupt, the chip selects of the profile's axes
  answering, and with ``motion`` the encoder counting and the index pulse;
* **busy**: the busy time after each of :data:`BUSY_COMMANDS`' command bytes, as far as the
  transport shows it (a far-side wait, then a status read), in the form ``sim://?busy=``
  takes, so the model can take what a chip shows.

The report (:class:`Report`) holds every measurement with the model's expected value; its JSON
form is :data:`SCHEMA` (checked by :func:`validate`), and :func:`compare` shows a saved report
against today's model.
"""

from __future__ import annotations

import json
import math
import platform
import statistics
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

from lm629_host.bus.opcodes import (
    BUSY_BIT,
    BUSY_WORST_CASE_S,
    COMMANDS,
    FIXED_ONE,
    SAMPLE_CLOCKS,
    Cmd,
    Status,
    TrajectoryFlags,
    s32_words,
)
from lm629_host.bus.program import Op, Program, ProgramResult
from lm629_host.chip.lm629 import LM629
from lm629_host.chip.safety import emergency_stop, stop_on_error
from lm629_host.chip.supervise import search_index
from lm629_host.errors import AxisError, LM629Error, ResetError, WaitTimeout
from lm629_host.transports import open_transport

#: the version of the report's JSON form (:data:`SCHEMA`); 2 added ``busy_resolution_us``
#: (a version 1 report is still read: its busy times are then shown, never compared)
SCHEMA_VERSION = 2
#: the clock run: long enough that a 6 MHz chip (25 % off 8 MHz) is unmistakable and a host
#: paused for part of it moves the median of the slopes by nothing
CLOCK_RUN_S = 0.5
CLOCK_ROWS = 50
#: a measured clock further than this from the profile's is a bench fault (crystals are
#: within 0.01 %; the measurement within 0.5 % on a busy host)
CLOCK_TOLERANCE = 0.03
#: the commands whose busy time after the command byte is measured (none of them acts: the
#: probe repeats each, and an action repeated within 10 ms is a fault of its own)
BUSY_COMMANDS = (Cmd.RDSIGS, Cmd.RDDP, Cmd.MSKI, Cmd.RSTI, Cmd.LPEI, Cmd.LTRJ)
#: the time base of the timed reads: 1/16 count per sample, so that the desired position
#: holds each whole count for 16 samples (4 ms at 8 MHz), longer than any one bus program
SLOW = FIXED_ONE // 16
#: the breakpoint of the velocity run, counts: reached after 8 x 16 samples
BREAKPOINT_AT = 8
#: a position-mode move with a long cruise at SLOW: the reads in its middle are in the cruise
CRUISE_TO = 40
#: how many samples of one whole count of the desired position the model is searched for the
#: chip's reads (four of the 16-sample counts, or as long after the end of a move)
PLATEAU_SAMPLES = 64
#: how many times the profile's sample rate a chip may run at when the model is run to the
#: chip's desired position: a chip clocked up to twice the profile's (a 6 MHz profile on an
#: 8 MHz chip is 1.33) is still caught up with; a desired position further on than that
#: since the STT is not where the model's time leads (the chip's differs), and the model is
#: compared where that time left it instead of being run to it (2^30 counts at 1/16 count a
#: sample would be hours of model time)
CHIP_RATE_MAX = 2.0
#: the verdicts and their exit codes (rows of the CLI's one table, ``lm629_host.cli.EXIT_CODES``:
#: 1 is every check's "found a problem", 10 the selftest's own "could not finish"; 2 is bad
#: usage, never a verdict)
EXIT = {"PASS": 0, "DIFFERS": 1, "FAIL": 10}
_READ_SIGNED16 = (Cmd.RDRV, Cmd.RDSUM)


@dataclass
class Measurement:
    """One thing measured, with what the model expects.  ``name`` is unique in a report (the
    step and the read); ``command`` the bus commands of the step up to this read; ``at`` the
    chip time base of a timed read (the desired position both sides were read at) and
    ``sample`` the model's samples since the step's STT there.  ``judged`` False: shown, never
    a difference (busy times: the transport's own overhead is in them)."""

    check: str  #: "core", "clock", "wiring", "busy"
    name: str
    command: str
    measured: Any
    expected: Any
    at: int | None = None
    sample: int | None = None
    judged: bool = True
    unit: str = ""

    @property
    def differs(self) -> bool:
        if not self.judged or self.measured is None:
            return False
        if self.check == "clock":
            return abs(self.measured - self.expected) > CLOCK_TOLERANCE * self.expected
        return bool(self.measured != self.expected)

    def show(self, value: Any) -> str:
        if isinstance(value, bool) or value is None:
            return str(value)
        if isinstance(value, int) and self.unit == "hex":
            return f"{value & 0xFFFF:04X}" if -0x8000 <= value <= 0xFFFF else f"{value:X}"
        if isinstance(value, float):
            return f"{value:.6g}{(' ' + self.unit) if self.unit else ''}"
        return f"{value}{(' ' + self.unit) if self.unit and self.unit != 'hex' else ''}"


@dataclass
class Fault:
    """A bench fault named with its fix: ``line`` is "clock", "HI", "index", "encoder" or
    "cs N"."""

    line: str
    message: str
    fix: str


@dataclass
class Report:
    """Everything one selftest found (its JSON form: :data:`SCHEMA`)."""

    versions: dict[str, str]
    transport: dict[str, str]
    profile: dict[str, Any]
    motion: bool
    measurements: list[Measurement] = field(default_factory=list)
    faults: list[Fault] = field(default_factory=list)
    #: why the script could not run to its end (None: it did)
    error: str | None = None
    schema: int = SCHEMA_VERSION
    #: the busy instrument's resolution, us: a busy time measured as ``command; wait;
    #: status`` is the shortest wait that reads busy clear, and the transport's own time
    #: between the wait and the status read (``Transport.busy_probe_us``) is in it, so the
    #: chip's busy time lies within [measured - 1, measured + this] (None: not stated)
    busy_resolution_us: int | None = None

    @property
    def differences(self) -> list[Measurement]:
        return [m for m in self.measurements if m.differs]

    @property
    def verdict(self) -> str:
        if self.error is not None:
            return "FAIL"
        return "DIFFERS" if self.faults or self.differences else "PASS"

    @property
    def exit_code(self) -> int:
        return EXIT[self.verdict]

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["verdict"] = self.verdict
        return d

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Report:
        """The report of :meth:`to_json`; ValueError listing what does not fit :data:`SCHEMA`."""
        problems = validate(data)
        if problems:
            raise ValueError("not a selftest report: " + "; ".join(problems[:5]))
        return cls(data["versions"], data["transport"], data["profile"], data["motion"],
                   [Measurement(**m) for m in data["measurements"]],
                   [Fault(**f) for f in data["faults"]], data["error"], data["schema"],
                   data.get("busy_resolution_us"))

    def busy_option(self) -> str:
        """The measured busy times as ``sim://?busy=`` takes them ("": none seen)."""
        seen = [m for m in self.measurements if m.check == "busy" and m.measured is not None]
        return ",".join(f"{m.name.split(': ')[1]}:{m.measured:g}" for m in seen)


def worst(verdicts: Sequence[str]) -> str:
    """The verdict of several selftests (a profile's axes): FAIL before DIFFERS before PASS."""
    order = ["PASS", "DIFFERS", "FAIL"]
    return max(verdicts, key=order.index, default="PASS")


#: the report's JSON form: every key, its type, and for the lists the keys of an item (types:
#: "str", "int", "bool", "dict", "list", "any", "str|null"...); :func:`validate` checks it
SCHEMA: dict[str, Any] = {
    "schema": "int",  # SCHEMA_VERSION
    "verdict": "str",  # PASS, DIFFERS or FAIL
    "versions": "dict",  # lm629_host, python, platform
    "transport": "dict",  # url, describe
    "profile": "dict",  # chip, clock_hz, cs, lines, path
    "motion": "bool",
    "error": "str|null",
    "busy_resolution_us": "int|null",  # us (schema 2 on; a version 1 report has none)
    "faults": [{"line": "str", "message": "str", "fix": "str"}],
    "measurements": [{"check": "str", "name": "str", "command": "str", "measured": "any",
                      "expected": "any", "at": "int|null", "sample": "int|null",
                      "judged": "bool", "unit": "str"}],
}
#: the keys a version 1 report does not have
_ADDED_IN_2 = ("busy_resolution_us",)
_TYPES: dict[str, tuple[type, ...]] = {"str": (str,), "int": (int,), "bool": (bool,),
                                       "dict": (dict,), "null": (type(None),)}


def _fits(value: Any, kind: str) -> bool:
    if kind == "any":
        return True
    ok = any(isinstance(value, _TYPES[k]) for k in kind.split("|"))
    return ok and not (kind.startswith("int") and isinstance(value, bool))


def validate(data: Any) -> list[str]:
    """What in ``data`` does not fit :data:`SCHEMA` (empty: a valid report)."""
    if not isinstance(data, dict):
        return ["the report is not a JSON object"]
    optional = _ADDED_IN_2 if data.get("schema") == 1 else ()
    problems = [f"missing key {k!r}" for k in SCHEMA if k not in data and k not in optional]
    problems += [f"unknown key {k!r}" for k in data if k not in SCHEMA]
    for key, kind in SCHEMA.items():
        if key not in data:
            continue
        if isinstance(kind, list):
            if not isinstance(data[key], list):
                problems.append(f"{key} is not a list")
                continue
            for i, item in enumerate(data[key]):
                if not isinstance(item, dict) or set(item) != set(kind[0]):
                    problems.append(f"{key}[{i}] does not have the keys {sorted(kind[0])}")
                    continue
                problems += [f"{key}[{i}].{k} is not {t}" for k, t in kind[0].items()
                             if not _fits(item[k], t)]
        elif not _fits(data[key], kind):
            problems.append(f"{key} is not {kind}")
    if not problems and data["schema"] not in (1, SCHEMA_VERSION):
        problems.append(f"schema {data['schema']}: this version reads 1 and {SCHEMA_VERSION}")
    if not problems and data["verdict"] not in EXIT:
        problems.append(f"verdict {data['verdict']!r} is not one of {', '.join(EXIT)}")
    return problems


# ---------------------------------------------------------------------- the steps
#: a step's items: ("w", Cmd, *words) a command with its words; ("r", Cmd) a read command;
#: ("s",) the status once busy is clear; ("p", builder) a program piece built from the chip
Item = tuple[Any, ...]


def _words_of(cmd: Cmd) -> int:
    return COMMANDS[cmd].words


def _program(chip: LM629, items: Sequence[Item]) -> tuple[Program, list[tuple[str, str]]]:
    """The step as one bus program, and (label, command text so far) of each value read."""
    p = chip.program()
    labels: list[tuple[str, str]] = []
    said: list[str] = []
    for item in items:
        kind = item[0]
        if kind == "w":
            p.command(item[1])
            for w in item[2:]:
                p.write(w)
            said.append(" ".join([item[1].name, *(f"{w:04X}" for w in item[2:])]))
        elif kind == "r":
            p.command(item[1]).read(_words_of(item[1]))
            said.append(item[1].name)
            labels.append((item[1].name, "; ".join(said)))
        elif kind == "s":
            p.sync()
            labels.append(("status", "; ".join(said) or "RDSTAT"))
        else:
            piece: Program = item[1](chip)
            p.extend(piece)
            said.append(_render(piece))
    return p, labels


def _render(piece: Program) -> str:
    out: list[str] = []
    for o in piece.ops:
        if o.op is Op.COMMAND:
            out.append(Cmd(o.arg).name)
        elif o.op is Op.WRITE and out:
            out[-1] += f" {o.arg:04X}"
    return "; ".join(out)


def _values(items: Sequence[Item], result: ProgramResult) -> list[int]:
    """The values a step read, in its labels' order (32-bit reads as signed counts)."""
    words = iter(result.words)
    statuses = iter(result.statuses)
    out = []
    for item in items:
        if item[0] == "r":
            n = _words_of(item[1])
            ws = [next(words) for _ in range(n)]
            if n == 2:
                out.append(s32_words(ws[0], ws[1]))
            elif item[1] in _READ_SIGNED16:
                out.append(ws[0] - 0x10000 if ws[0] & 0x8000 else ws[0])
            else:
                out.append(ws[0])
        elif item[0] == "s":
            out.append(next(statuses) & ~BUSY_BIT)
    return out


class Lockstep:
    """The chip and the model, the same steps on both.  ``chip`` None: the model alone,
    replaying the chip times of a saved report (``replay``: name -> measurement)."""

    def __init__(self, chip: LM629 | None, model: LM629,
                 replay: dict[str, Measurement] | None = None) -> None:
        self.chip = chip
        self.model = model
        self.replay = replay or {}
        self.out: list[Measurement] = []
        self._stt_sample = 0
        self._stt_time = 0.0  #: the chip's clock at the last STT

    def sides(self) -> list[LM629]:
        return [self.model] if self.chip is None else [self.chip, self.model]

    def pause(self, seconds: float) -> None:
        """Let time pass on both (the 10 ms between two STTs, AN-706 4.6.2)."""
        for side in self.sides():
            side.clock.sleep(seconds)

    def _record(self, name: str, labels: list[tuple[str, str]], got: list[int] | None,
                want: list[int], at: int | None = None, sample: int | None = None) -> None:
        for k, (label, command) in enumerate(labels):
            unit = "counts" if label in ("RDDP", "RDRP", "RDIP") else "hex"
            self.out.append(Measurement("core", f"{name}: {label}", command,
                                        None if got is None else got[k], want[k], at, sample,
                                        unit=unit))

    def step(self, name: str, items: Sequence[Item]) -> list[int]:
        """Run ``items`` on both; every read compared.  Returns the model's values."""
        got = None
        if self.chip is not None:
            program, labels = _program(self.chip, items)
            got = _values(items, self.chip.run(program))
        program, labels = _program(self.model, items)
        want = _values(items, self.model.run(program))
        self._record(name, labels, got, want)
        return want

    def started(self) -> None:
        """An STT just went to both: the model's samples count from here."""
        self._stt_sample = self._samples()
        if self.chip is not None:
            self._stt_time = self.chip.clock.now()

    def _samples(self) -> int:
        return int(self.model.clock.now() * self.model.clock_hz) // SAMPLE_CLOCKS

    def _bracketed(self, chip: LM629, items: Sequence[Item]) -> tuple[int, list[int], bool | None]:
        """``items`` between two RDDP reads, until both read the same whole count (no sample
        boundary changed the time base in between): (desired position, values, HI)."""
        whole = [("r", Cmd.RDDP), *items, ("r", Cmd.RDDP)]
        for _attempt in range(8):
            program, _labels = _program(chip, whole)
            result = chip.run(program)
            values = _values(whole, result)
            if values[0] == values[-1]:
                return values[0], values[1:-1], result.hi
        raise LM629Error("the desired position changed within every one of 8 bracketed reads: "
                         "the time base is not slow enough for this adapter")

    def _run_model_to(self, at: int, per_sample: float, most: float) -> None:
        """Run the model to the first sample at which its desired position reads ``at``: in
        strides that end at least a count short (at most ``per_sample`` counts a sample),
        then a sample at a time; no further than ``most`` samples since the STT (where the
        chip could have got by then: a chip that reads further on differs)."""
        period = SAMPLE_CLOCKS / self.model.clock_hz
        for _ in range(100_000):
            gap = at - self.model.read_desired_position()
            left = most - (self._samples() - self._stt_sample)
            if gap <= 0 or left < 1:
                return
            stride = min(int((gap - 1) / per_sample), int(left))
            if stride > 1:
                self.model.clock.sleep(stride * period)
            else:
                self._next_sample(period)
        raise LM629Error(f"the model never reached the desired position {at}")

    def _next_sample(self, period: float) -> None:
        """Run the model just past its next sample (a bracketed read lasts less than a
        sample, so the next one then reads that sample alone)."""
        now = self.model.clock.now()
        self.model.clock.sleep((math.floor(now / period) + 1.05) * period - now)

    def timed(self, name: str, items: Sequence[Item], *, per_sample: float,
              hi: bool = False) -> tuple[list[int], bool | None, bool | None]:
        """``items`` at one chip time on both: read on the chip, then on the model run to
        the same desired position.  The chip may have been read at any sample of that whole
        count (16 of them at 1/16 count a sample, or any time after the end of a move, if
        the host was late): the model is compared at the first of those samples whose reads
        are the chip's, else at the first.  Returns the model's values and HI on chip and
        model."""
        _unused, labels = _program(self.model, items)
        got: list[int] | None = None
        chip_hi: bool | None = None
        period = SAMPLE_CLOCKS / self.model.clock_hz
        most = math.inf
        if self.chip is not None:
            at, got, chip_hi = self._bracketed(self.chip, items)
            most = (self.chip.clock.now() - self._stt_time) / period * CHIP_RATE_MAX
        else:
            saved = self.replay.get(f"{name}: RDDP")
            at = saved.at if saved is not None and saved.at is not None else 0
            if saved is not None and saved.sample is not None:
                most = saved.sample
            kept = [self.replay.get(f"{name}: {label}") for label, _ in labels]
            got = [m.measured for m in kept if m is not None] if all(kept) else None
        self._run_model_to(at, per_sample, most + PLATEAU_SAMPLES)
        plateau: list[tuple[int, list[int], bool | None, int]] = []
        for _ in range(PLATEAU_SAMPLES):
            at_model, want, model_hi = self._bracketed(self.model, items)
            reading = (at_model, want, model_hi, self._samples() - self._stt_sample)
            if at_model != at:  # the model left (or never reached) the chip's whole count
                break
            plateau.append(reading)
            if got is None or want == got:
                break
            self._next_sample(period)
        if plateau and (got is None or plateau[-1][1] != got):
            reading = plateau[0]  # no sample matched: the differences are shown at the first
        elif plateau:
            reading = plateau[-1]
        at_model, want, model_hi, sample = reading
        self._record(name, [("RDDP", "RDDP"), *labels],
                     None if got is None or self.chip is None else [at, *got],
                     [at_model, *want], at, sample)
        if hi:
            self.out.append(Measurement("wiring", f"{name}: HI pin", "HI after the reads",
                                        chip_hi, model_hi, at, sample,
                                        judged=chip_hi is not None))
        return want, chip_hi, model_hi


# ---------------------------------------------------------------------- the script
def _core(ls: Lockstep) -> Fault | None:
    """The digital core, motor off (filter gains 0: the trajectory runs, nothing drives).
    Returns the fault that stopped it early (positions that are not the model's after a
    reset: no timed read could be matched), else None."""
    for side in ls.sides():
        side.reset()
    ls.out.append(Measurement("core", "reset: status", "/RST (or RESET); MSKI; RSTI",
                              None if ls.chip is None else int(ls.chip.read_status()),
                              int(ls.model.read_status()), unit="hex"))
    every = [("r", c) for c in (Cmd.RDSIGS, Cmd.RDDP, Cmd.RDRP, Cmd.RDDV, Cmd.RDRV, Cmd.RDSUM,
                                Cmd.RDIP)]
    ls.step("after reset", [("s",), *every])
    fault = _positions_fault(ls)
    if fault is not None:
        return fault
    ls.step("masks", [("w", Cmd.MSKI, int(Status.BREAKPOINT)), ("w", Cmd.LPEI, 0x7FFF),
                      ("w", Cmd.SBPA, 0, BREAKPOINT_AT), ("w", Cmd.RSTI, 0), ("s",),
                      ("r", Cmd.RDSIGS)])
    # UDF acts at the next sample, which sets signals bit 13 for that one sample: read once
    # two samples have surely passed, never right after (on a bench a sample may pass
    # within the program, on the model it does not)
    ls.step("filter 0", [("p", lambda c: c.filter_program(kp=0, ki=0, kd=0, il=0)),
                         ("w", Cmd.UDF), ("s",)])
    ls.pause(0.002)
    ls.step("filter updated", [("s",), ("r", Cmd.RDSIGS)])
    # velocity mode at 1/16 count a sample: the breakpoint interrupt, HI, RDDP over time
    ls.step("velocity start", [("p", lambda c: c.trajectory_program(
        acceleration=SLOW, velocity=SLOW, velocity_mode=True)), ("w", Cmd.STT), ("s",),
        ("r", Cmd.RDSIGS)])
    ls.started()
    reads = [("s",), ("r", Cmd.RDSIGS), ("r", Cmd.RDDV), ("r", Cmd.RDRP)]
    if ls.chip is not None:
        ls.chip.clock.sleep(0.004)
    ls.timed("velocity before the breakpoint", reads, per_sample=1 / 16, hi=True)
    if ls.chip is not None:
        ls.chip.clock.sleep((BREAKPOINT_AT + 3) * 16 * SAMPLE_CLOCKS / ls.model.clock_hz)
    ls.timed("velocity past the breakpoint", reads, per_sample=1 / 16, hi=True)
    ls.step("interrupt reset", [("w", Cmd.RSTI, 0), ("s",), ("r", Cmd.RDSIGS)])
    ls.pause(0.012)
    # the stop from 1/16 count a sample ends at the next sample: its status is read after
    ls.step("stop smooth", [("p", lambda c: c.trajectory_program(stop="smooth")),
                            ("w", Cmd.STT)])
    ls.pause(0.012)
    ls.step("stopped", [("s",), ("r", Cmd.RDSIGS), ("r", Cmd.RDDV)])
    # position mode: a cruise at 1/16 count a sample, read in its middle and at its end
    target = ls.model.read_desired_position() + CRUISE_TO
    ls.step("position start", [("w", Cmd.RSTI, 0), ("p", lambda c: c.trajectory_program(
        acceleration=SLOW // 4, velocity=SLOW, position=target)), ("w", Cmd.STT), ("s",)])
    ls.started()
    if ls.chip is not None:
        ls.chip.clock.sleep(CRUISE_TO / 2 * 16 * SAMPLE_CLOCKS / ls.model.clock_hz)
    ls.timed("position cruising", reads, per_sample=1 / 16)
    for side in ls.sides():
        side.wait_for(Status.TRAJECTORY_COMPLETE, timeout=2 * CRUISE_TO * 16 * SAMPLE_CLOCKS
                      / ls.model.clock_hz + 1.0, what="the position-mode move to complete")
    ls.step("position done", [("s",), ("r", Cmd.RDSIGS), ("r", Cmd.RDDP), ("r", Cmd.RDDV)])
    ls.step("index armed", [("w", Cmd.SIP), ("s",), ("r", Cmd.RDSIGS), ("r", Cmd.RDIP)])
    ls.step("home", [("w", Cmd.DFH), ("s",), ("r", Cmd.RDDP), ("r", Cmd.RDRP)])
    ls.pause(0.012)
    ls.step("motor off", [("p", lambda c: c.trajectory_program(stop="off")), ("w", Cmd.STT),
                          ("s",), ("r", Cmd.RDSIGS)])
    # the one command an LM628 takes and an LM629 refuses (its command-error bit): sent on
    # either profile, motor off, so that an LM628 on an LM629 profile (or the other way
    # round) is named; PORT8 and an RSTI after it leave the chip as before
    ls.step("12-bit port", [("w", Cmd.RSTI, 0), ("w", Cmd.PORT12), ("s",), ("r", Cmd.RDSIGS)])
    ls.step("8-bit port", [("w", Cmd.PORT8), ("w", Cmd.RSTI, 0), ("s",), ("r", Cmd.RDSIGS)])
    return None


def _positions_fault(ls: Lockstep) -> Fault | None:
    """The chip's positions after its reset where the model's are 0 (a chip reset by
    something else, a simulator's ``reset_position``): every timed read of the core is taken
    at the chip's desired position, which the model would have to be run to from 0 (hours of
    model time, or never): the core stops, saying so."""
    read = {m.name: m.measured for m in ls.out[-8:] if m.measured is not None}
    want = {m.name: m.expected for m in ls.out[-8:]}
    names = ("after reset: RDDP", "after reset: RDRP")
    if not all(n in read for n in names) or all(read[n] == want[n] for n in names):
        return None
    dp, rp = (read[n] for n in names)
    return Fault("positions", f"the chip's desired and real positions read {dp} and {rp} after "
                              f"its reset, where a reset leaves {want[names[0]]} and "
                              f"{want[names[1]]}: its positions are not the model's, so no "
                              "timed read can be matched (the core stopped there)",
                 "check that the reset reaches this chip (/RST, pin 27; or the RESET command "
                 "on a bridge without the line) and that nothing else drives it; a simulator's "
                 "reset_position= makes exactly this")


def _variant_fault(ls: Lockstep) -> Fault | None:
    """An LM628 where the profile says LM629, or the other way round: PORT12's command-error
    bit (status bit 1) on the chip is not the model's."""
    m = next((m for m in ls.out if m.name == "12-bit port: status"), None)
    if m is None or m.measured is None or not (m.measured ^ m.expected) & Status.COMMAND_ERROR:
        return None
    profile = ls.model.variant.upper()
    chip = "LM628" if profile == "LM629" else "LM629"
    took = "took PORT12 (the 12-bit DAC port) without" if chip == "LM628" else \
        "refused PORT12 (the 12-bit DAC port) with"
    return Fault("chip", f"the chip {took} a command error: it is an {chip}, the profile says "
                         f"{profile}",
                 f"set the profile's chip to \"{chip.lower()}\" (or --chip {chip.lower()}) if "
                 f"that is the part on the board (an LM628 drives a DAC, an LM629 PWM)")


def _hi_fault(ls: Lockstep) -> Fault | None:
    past = next((m for m in ls.out if m.name == "velocity past the breakpoint: HI pin"), None)
    before = next((m for m in ls.out if m.name == "velocity before the breakpoint: HI pin"), None)
    if past is None or before is None or past.measured is None:
        return None
    if past.expected and not past.measured:
        return Fault("HI", "HI (pin 17) stayed low while the chip raised its breakpoint "
                           "interrupt (signals bit 15 set): HI is not wired to the adapter",
                     "connect LM629 pin 17 (HI) to the adapter's HI input (the Uno's A5, the "
                     "FT232H's ADBUS5: `lm629 wiring` shows yours)")
    if before.measured and not before.expected:
        return Fault("HI", "HI (pin 17) read high with no interrupt pending: the line is stuck "
                           "high or wired to another signal",
                     "check the HI wire for a short to +5 V or a neighbouring pin")
    return None


def _clock(ls: Lockstep, profile_hz: float) -> Fault | None:
    """The sample period against the transport's clock, from a velocity run at one count a
    sample (filter gains 0) recorded for :data:`CLOCK_RUN_S`."""
    chip = ls.chip
    expected = profile_hz / 1e6
    if chip is None:
        ls.out.append(Measurement("clock", "clock: measured", "velocity run, RDDP recorded",
                                  ls.replay["clock: measured"].measured
                                  if "clock: measured" in ls.replay else None, expected,
                                  unit="MHz"))
        return None
    chip.reset()
    chip.load_filter(kp=0, ki=0, kd=0, il=0)
    chip.update_filter()
    chip.load_trajectory(acceleration=FIXED_ONE, velocity=FIXED_ONE, velocity_mode=True,
                         start=True)
    try:
        trace = chip.record(CLOCK_RUN_S / CLOCK_ROWS, CLOCK_RUN_S)
    finally:
        chip.load_trajectory(stop="off", start=True)
    rows = list(trace)
    half = len(rows) // 2
    slopes = [(rows[i + half].desired - rows[i].desired) / (rows[i + half].t - rows[i].t)
              for i in range(len(rows) - half) if rows[i + half].t > rows[i].t]
    if not slopes:
        raise LM629Error("the clock run recorded too few rows to measure the sample period")
    mhz = statistics.median(slopes) * SAMPLE_CLOCKS / 1e6
    m = Measurement("clock", "clock: measured", f"velocity run at 1 count/sample, RDDP "
                    f"recorded {len(rows)} times over {CLOCK_RUN_S:g} s "
                    f"({chip.transport.record_note()})", round(mhz, 4), expected, unit="MHz")
    ls.out.append(m)
    if not m.differs:
        return None
    return Fault("clock", f"the chip's clock measures {mhz:.2f} MHz (sample period "
                          f"{SAMPLE_CLOCKS / mhz:.1f} us); the profile says {expected:g} MHz: "
                          f"every velocity and time is {abs(mhz / expected - 1) * 100:.0f} % off",
                 f"set the profile's clock to \"{mhz:.3g}MHz\" (or --clock {mhz:.3g}MHz) if "
                 "that is the crystal on the board; otherwise check the crystal and its "
                 "oscillator")


def _busy_after(chip: LM629, cmd: Cmd, wait_us: int) -> bool:
    """True when the chip reads busy ``wait_us`` after ``cmd``'s command byte (the command
    then completed normally, so nothing is left half done)."""
    p = chip.program().command(cmd)
    if wait_us:
        p.wait(wait_us)
    p.status()
    if COMMANDS[cmd].direction.value == "read":
        p.read(_words_of(cmd))
    elif cmd is Cmd.LTRJ:
        p.write(int(TrajectoryFlags.VELOCITY_MODE | TrajectoryFlags.FORWARD))
    elif cmd is Cmd.MSKI:
        p.write(int(Status.BREAKPOINT))
    elif cmd is Cmd.LPEI:
        p.write(0x7FFF)
    else:
        p.write(0)
    return bool(chip.run(p).statuses[0] & BUSY_BIT)


def _busy_time(chip: LM629, cmd: Cmd) -> int | None:
    """The shortest far-side wait after which busy reads clear, us (None: never seen busy:
    the transport waits it out itself)."""
    if not _busy_after(chip, cmd, 0):
        return None
    lo, hi = 0, int(BUSY_WORST_CASE_S * 1e6) + 1  # busy at lo; at hi assumed clear
    if _busy_after(chip, cmd, hi):
        return hi
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if _busy_after(chip, cmd, mid):
            lo = mid
        else:
            hi = mid
    return hi


def _busy(ls: Lockstep) -> None:
    for cmd in BUSY_COMMANDS:
        got = None if ls.chip is None else _busy_time(ls.chip, cmd)
        if ls.chip is None and f"busy: {cmd.name}" in ls.replay:
            got = ls.replay[f"busy: {cmd.name}"].measured
        ls.out.append(Measurement("busy", f"busy: {cmd.name}", f"{cmd.name}, wait, RDSTAT",
                                  got, _busy_time(ls.model, cmd), judged=False, unit="us"))


def _selects(chip: LM629, selects: Sequence[int], out: list[Measurement]) -> list[Fault]:
    """Each chip select of the profile's axes answers with a status that is not FF (the
    undriven bus's pull-ups)."""
    faults = []
    for cs in selects:
        try:
            other = chip if cs == chip.chip_select else LM629(
                chip.transport, chip=chip.variant, axis=cs if cs else None)
            status = int(other.read_status())
        except AxisError as exc:
            out.append(Measurement("wiring", f"cs {cs}: answers", "RDSTAT", False, True))
            faults.append(Fault(f"cs {cs}", str(exc), "give the axis a chip select the adapter "
                                                       "has (`lm629 wiring` lists them)"))
            continue
        out.append(Measurement("wiring", f"cs {cs}: answers", "RDSTAT", status != 0xFF, True))
        if status == 0xFF:
            faults.append(Fault(f"cs {cs}", f"no chip answers on chip select {cs} (status "
                                            "reads FF: nothing drives the bus)",
                                f"check /CS {cs}'s wire to pin 12 of that chip, and the chip's "
                                "power and clock"))
    return faults


def _motion(ls: Lockstep, lines: int, gains: dict[str, int]) -> list[Fault]:
    """The encoder counting and the index pulse: a slow velocity run (about a quarter turn a
    second) until the index is latched, with stop-on-error armed (an encoder that does not
    count makes the following error grow: the chip then turns the motor off itself)."""
    counts_per_rev = 4 * lines
    faults: list[Fault] = []
    counted: bool | None = None
    index: bool | None = None
    for side in ls.sides():
        period = SAMPLE_CLOCKS / side.clock_hz
        velocity = max(1, round(counts_per_rev / 4 * period * FIXED_ONE))
        side.reset()
        side.load_filter(**gains)
        side.update_filter()
        side.load_position_error(max(200, counts_per_rev // 8), stop=True)
        seen = True
        with stop_on_error(side):
            try:
                search_index(side, velocity, timeout=4 * 2.5 + 1.0)
            except WaitTimeout:
                seen = False
                emergency_stop(side)
        moved = abs(side.read_real_position())
        side.reset()
        if side is ls.model:
            ls.out.append(Measurement("wiring", "motion: encoder counts", "velocity run",
                                      counted, moved > 1))
            ls.out.append(Measurement("wiring", "motion: index seen", "SIP; velocity run",
                                      index, seen))
        else:
            counted, index = moved > 1, seen
            if not counted:
                faults.append(Fault("encoder", "the real position did not change while the "
                                               "chip drove the motor: the encoder does not count "
                                               "(or the shaft did not turn)",
                                    "check the encoder's A and B (pins 2, 3) and its supply; "
                                    "then the amplifier and the motor"))
            elif not seen:
                faults.append(Fault("index", "no index pulse in 2.5 revolutions while the "
                                             "encoder counted: the index is not wired",
                                    "connect the encoder's index channel to LM629 pin 1 (IN); "
                                    "an encoder without one cannot home on the index"))
    return faults


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


#: the samples a SIP is given, motor off, to latch an index under the shaft
INDEX_PROBE_SAMPLES = 3
#: the name of the index probe's measurement (shown, never judged: where a shaft rests is
#: the bench's business)
INDEX_AT_REST = "index: under the shaft at rest"


def index_at_rest(chip: LM629) -> bool:
    """True when the shaft rests on the encoder's index: after a reset (motor off) a SIP
    latches the index within :data:`INDEX_PROBE_SAMPLES` samples with nothing turning.  The
    model's index is half a turn from its shaft (model choice 20), so a bench parked on its
    index would read INDEX_PULSE after SIP and DFH where the model does not: the model is
    built with its index under its shaft instead."""
    chip.reset()
    chip.run(chip.program().command(Cmd.SIP))
    chip.clock.sleep(INDEX_PROBE_SAMPLES * SAMPLE_CLOCKS / chip.clock_hz)
    return bool(chip.read_status() & Status.INDEX_PULSE)


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
            stopped = _core(ls)
            report.faults += [stopped] if stopped else []
            for fault in (_hi_fault(ls), _variant_fault(ls)):
                report.faults += [fault] if fault else []
            progress("clock: the sample period")
            fault = _clock(ls, options.profile_hz)
            report.faults += [fault] if fault else []
            progress("busy: after each command byte")
            _busy(ls)
            report.faults += _selects(chip, options.selects or (chip.chip_select,), ls.out)
            chip.limits = limits
            if options.motion:
                progress("motion: the encoder and the index")
                report.faults += _motion(ls, options.lines, options.gains)
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
        _core(ls)
        _clock(ls, options.profile_hz)
        _busy(ls)
        if saved.motion:
            _motion(ls, options.lines, options.gains)
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


def summary_markdown(report: Report) -> str:
    """A short Markdown summary a user can paste into an issue."""
    out = [f"## lm629 selftest: {report.verdict}", "",
           f"* lm629_host {report.versions['lm629_host']}, Python {report.versions['python']}",
           f"* transport: `{report.transport['describe']}`",
           f"* profile: {report.profile['chip'].upper()} at {report.profile['clock_hz'] / 1e6:g} "
           f"MHz, cs {report.profile['cs']}, motion {'on' if report.motion else 'off'}",
           f"* {len(report.measurements)} measurements, {len(report.differences)} differ"]
    if report.error:
        out.append(f"* could not finish: {report.error}")
    for f in report.faults:
        out.append(f"* **{f.line}**: {f.message}; fix: {f.fix}")
    if report.differences:
        out += ["", "| measurement | commands | chip | model |", "|---|---|---|---|"]
        out += [f"| {m.name} | `{m.command}` | {m.show(m.measured)} | {m.show(m.expected)} |"
                for m in report.differences[:20]]
    busy = report.busy_option()
    if busy:
        within = ("" if report.busy_resolution_us is None else
                  f" (each -1 to +{report.busy_resolution_us} us: this transport's resolution)")
        out += ["", f"The model with this chip's busy times{within}: `sim://?busy={busy}`"]
    return "\n".join(out) + "\n"


def write_report(report: Report, path: str) -> str:
    """Write the JSON report to ``path`` and the Markdown summary beside it (``.md``);
    returns the summary's path."""
    from pathlib import Path
    target = Path(path)
    target.write_text(json.dumps(report.to_json(), indent=1) + "\n")
    md = target.with_suffix(".md")
    md.write_text(summary_markdown(report))
    return str(md)


def load_report(path: str) -> Report:
    """A report written by :func:`write_report`; ValueError naming the file and what is wrong."""
    from pathlib import Path
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: {exc}") from None
    try:
        return Report.from_json(data)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


__all__ = ["BUSY_COMMANDS", "CLOCK_TOLERANCE", "EXIT", "Fault", "INDEX_AT_REST", "Lockstep",
           "Measurement", "Options", "Report", "SCHEMA", "SCHEMA_VERSION", "compare",
           "index_at_rest", "load_report", "reference", "run", "summary_markdown", "validate",
           "worst", "write_report"]
