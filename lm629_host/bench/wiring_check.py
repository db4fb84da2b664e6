"""The wiring check: find the wrong wire between the adapter and the LM629, moving nothing.

``lm629 wiring --check`` runs :func:`check_wiring`; bring-up runs it when the reset fails.

How it moves nothing.  Every experiment starts from a hardware reset, which leaves the filter
at zero gain (kp = ki = kd = 0: the spec's "What reset sets") and the motor off.  The check never
sends LFIL, so no bent byte can load a gain: a trajectory runs its desired position to the
loaded target with zero drive (the shaft stays), and RDDP reads that target back.  It ends with
/RST: motor off, the chip left reset.

What it looks at (each from a fresh /RST, the AN-706 4.4.1 statuses as a guide):

* the status right after /RST (00: the chip drives it, no command is involved) and 1.5 ms
  later (84 or C4): the read path alone;
* RSTI 0000, then the status (80 or C0);
* RDDP, RDSIGS and SBPA after /RST, and SBPA alone: command bytes that differ from LTRJ's
  and RSTI's where the faults that turn those into other commands differ;
* LTRJ (absolute position, velocity, acceleration), STT, RDDP: two patterns whose bytes put
  0 and 1 on every line (``000055AA``, ``FFFFAA55``), and a relative move after one (the
  chip adds: a swapped pair shows there although a pattern read back through the same two
  wires comes back right); the status after each move (04 or 44: motor on, trajectory done).

How it decides.  Each suspect wire (every line stuck low, stuck high or open, every pair
swapped) is a :class:`~lm629_host.wiring.faults.Miswiring`; the check predicts what the host would
read through it wherever the prediction does not need the chip's reaction to a bent command
(the statuses from /RST always; an experiment whose command bytes and control word the fault
leaves alone), and keeps the suspects that explain every reading.  A correct bench is the
suspect "no fault".  When none explains them (two faults, a control line), the readings that
went wrong are reported with the lines they differ on.  Control lines: FF everywhere (no chip
drives the bus: /CS, /RD, power, clock), 00 long after /RST (the chip stays in reset), a
status after /RST that is not 00 (/RST does not reach the chip), busy that never clears, HI
that does not follow the interrupt flags.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from lm629_host.urls import PortURL, scheme_of
from lm629_host.wiring.connections import MAX_AXES, adapter_name, adapter_pin, connections
from lm629_host.errors import BusyTimeout, LM629Error
from lm629_host.wiring.faults import Miswiring
from lm629_host.bus.opcodes import (
    NOMINAL_CLOCK_HZ,
    RESET_CLEARED_STATUSES,
    RESET_DONE_STATUSES,
    RESET_WAIT_S,
    UPDATE_INTERVAL_S,
    Cmd,
)
from lm629_host.bus.pinout import pin_of
from lm629_host.physics.plan import plan
from lm629_host.bus.program import Op, Program
from lm629_host.wiring.reference import READINGS, WHAT

if TYPE_CHECKING:
    from lm629_host.chip.lm629 import LM629

#: the AN-706 statuses: at once after /RST, 1.5 ms later, after RSTI 0000
AT_RESET = frozenset({0x00})
RESET_DONE = frozenset(RESET_DONE_STATUSES)
CLEARED = frozenset(RESET_CLEARED_STATUSES)
#: RDSIGS after /RST: the 8-bit output mode (bit 8), the status byte's bits (busy apart), the
#: host interrupt (bit 15) set or not (a published run reads 01C0; the chip model 81C4: HI high
#: while trajectory complete is an unmasked flag)
SIGNALS_AFTER_RESET = frozenset(hi | 0x0100 | s for hi in (0, 0x8000) for s in RESET_DONE | CLEARED)
#: after a move with the drive on (zero gain): trajectory complete, breakpoint latched or not,
#: position error (bit 5) set or not: the patterns stay within the threshold /RST sets, but a
#: load that turns the shaft while the drive is zero (an arm under gravity) can add to it
MOVED = frozenset({0x04, 0x44, 0x24, 0x64})
#: LTRJ control word: absolute position, velocity and acceleration; and a relative position
LTRJ_FULL = 0x002A
LTRJ_RELATIVE = 0x0003
#: the largest acceleration and velocity (16.16 counts/sample, 30 bits): a pattern is reached
#: in a few samples
ACCEL = VELOCITY = 0x3FFF0000
#: the patterns: every data line carries a 0 and a 1 in each (high bytes 00 and FF); within the
#: position-error threshold a hardware reset sets (7FFF), so no status bit but the ones above
PATTERNS = (0x000055AA, 0xFFFFAA55)
#: absolute then relative: the chip's sum shows swapped lines
RELATIVE = (0x00001357, 0x00000A35)
#: the position-error threshold a hardware reset sets (the motor stays, so the error is the
#: desired position)
POSITION_ERROR_THRESHOLD = 0x7FFF
#: how long a move is given: 16 samples at the slowest clock the chip runs (1 MHz: 2 ms a
#: sample) would be 32 ms; at 6-8 MHz a pattern is reached in 3-4 samples (1.4 ms)
MOVE_WAIT_US = 4000
#: two STTs at least this far apart (AN-706 4.6.2: a new STT aborts the trajectory calculation)
UPDATE_WAIT_US = round(UPDATE_INTERVAL_S * 1e6)
#: the wait before every transfer (the datasheet's longest busy is 100 us)
UNHURRIED_US = 150
#: the reset wait in the microseconds a bus program's wait takes
RESET_WAIT_US = round(RESET_WAIT_S * 1e6)


def _signed32(v: int) -> int:
    v &= 0xFFFFFFFF
    return v - (1 << 32) if v & 0x80000000 else v


def _bend32(value: int, bend: Callable[[int], int]) -> int:
    return sum(bend((value >> s) & 0xFF) << s for s in (24, 16, 8, 0))


@dataclass
class Reading:
    """One thing read: what a correct bench gives (any of ``expected``) and what came."""

    what: str  #: "status 1.5 ms after /RST", "RDDP after 000055AA"...
    expected: frozenset[int]
    got: int | None  #: None: the program failed before (``error``)
    error: str = ""
    experiment: str = ""
    size: int = 1  #: bytes: 1 (a status), 2 (RDSIGS), 4 (a position)
    #: the exception that ended the program before the reading (``error`` is its first line)
    exception: LM629Error | None = None

    def ok(self) -> bool:
        """Read, and as expected (an empty ``expected``: any value)."""
        return self.got is not None and (not self.expected or self.got in self.expected)

    def show(self, v: int | None) -> str:
        if v is None:
            return "nothing"
        return f"{v:0{2 * self.size}X}"

    def describe(self) -> str:
        exp = " or ".join(self.show(e) for e in sorted(self.expected)) or "any value"
        got = self.error or self.show(self.got)
        return f"{self.what}: read {got}, expected {exp}"


@dataclass
class Experiment:
    """The bytes an experiment writes that a bent wire may turn into another command."""

    name: str
    commands: tuple[int, ...]
    words: tuple[int, ...]  #: control and data words whose bending changes the experiment
    target: int | None = None  #: the position a move goes to (None: no move)
    relative: int | None = None  #: a relative move after it
    busy: bool = True  #: has busy-checked operations


@dataclass
class Suspect:
    """One line of the report: an LM629 line, its pin, the adapter's pin, what was seen."""

    line: str
    message: str


@dataclass
class WiringReport:
    adapter: str
    readings: list[Reading] = field(default_factory=list)
    suspects: list[Suspect] = field(default_factory=list)
    hi_seen: list[bool] = field(default_factory=list)
    #: counts the shaft turned during the check (None: not known, a data line is suspect)
    travel: int | None = None

    @property
    def passed(self) -> bool:
        return not self.suspects

    def lines(self) -> list[str]:
        if self.passed:
            moved = "" if self.travel is None else (
                f"; the shaft turned {self.travel} count(s) (zero-gain filter)")
            return [f"wiring check: every data line passed ({len(self.readings)} readings: "
                    "/RST statuses, RSTI, RDDP, RDSIGS, SBPA, patterns 000055AA and FFFFAA55, "
                    f"a relative move){moved}; the chip is left reset, motor off"]
        return [s.message for s in self.suspects]


# ---------------------------------------------------------------------- predictions
def _predict_status(bend: Miswiring, expected: frozenset[int]) -> frozenset[int]:
    return frozenset(bend.to_host(e) for e in expected)


def _clean(bend: Miswiring, exp: Experiment) -> bool:
    """True when the fault leaves the experiment's commands and control words alone, so that
    the chip runs what the host meant (only the data bytes are bent)."""
    return all(bend.to_chip(c) == c for c in exp.commands) and all(
        _bend32(w, bend.to_chip) == w for w in exp.words)


def _busy_seen(bend: Miswiring) -> tuple[bool, bool]:
    """(always, maybe): the host reads busy set through ``bend`` in every / some status the
    chip shows after its reset (84 or C4): then the first busy check times out."""
    busy = [bool(bend.to_host(s) & 1) for s in RESET_DONE]
    return all(busy), any(busy)


def _stuck(bend: Miswiring, got: int, size: int) -> bool:
    """Every byte of ``got`` has the stuck lines at their level (true whatever the chip sent:
    the read is bent on the way back)."""
    for shift in range(0, 8 * size, 8):
        b = (got >> shift) & 0xFF
        if b & bend.low or ~b & bend.high:
            return False
    return True


def _predict(bend: Miswiring, reading: Reading,
             exp: Experiment | None) -> Callable[[int | None], bool] | None:
    """A test of what ``reading`` would give through ``bend``; None: anything goes (the chip
    ran a command the fault made of another, and only the chip knows what it does with it)."""
    if exp is None:  # the statuses from /RST: no command involved
        want = _predict_status(bend, reading.expected)
        return lambda got: got in want
    always, maybe = _busy_seen(bend) if exp.busy else (False, False)
    p = _predict_data(bend, reading, exp)
    if always or maybe:
        # busy reads set: a busy check times out (nothing read), or runs the transfer once a
        # later status reads clear (the FT232H checks after the fact and repeats)
        return lambda got: got is None or p is None or p(got)
    return p


def _predict_data(bend: Miswiring, reading: Reading,
                  exp: Experiment) -> Callable[[int | None], bool] | None:
    """:func:`_predict` for a program that ran (no busy check failed)."""
    size = reading.size
    if not _clean(bend, exp) or not _completes(bend, exp):
        if not (bend.low | bend.high):
            return None
        return lambda got: got is None or _stuck(bend, got, size)
    if not reading.expected:  # any value: only what a stuck line makes of every byte
        if not (bend.low | bend.high):
            return lambda got: got is not None
        return lambda got: got is not None and _stuck(bend, got, size)
    if size == 2:
        want = frozenset(_bend32(e, bend.to_host) for e in reading.expected)
        return lambda got: got in want
    if exp.target is None and size == 4:
        want = frozenset(_bend32(e, bend.to_host) for e in reading.expected)
        return lambda got: got in want
    if size == 1:
        expected = reading.expected
        if exp.target is not None and abs(_target(bend, exp)) > POSITION_ERROR_THRESHOLD:
            expected = frozenset(e | 0x20 for e in expected)  # the chip flags the error
        want = _predict_status(bend, expected)
        return lambda got: got in want
    value = _bend32(_target(bend, exp) & 0xFFFFFFFF, bend.to_host)
    return lambda got: got == value


def _target(bend: Miswiring, exp: Experiment) -> int:
    """Where the chip's trajectory goes when the fault bends the data words."""
    assert exp.target is not None
    target = _signed32(_bend32(exp.target, bend.to_chip))
    if exp.relative is not None:
        target = _signed32(target + _signed32(_bend32(exp.relative, bend.to_chip)))
    return target


def _completes(bend: Miswiring, exp: Experiment) -> bool:
    """The experiment's move (if any) ends within its wait with the bent acceleration,
    velocity and target (judged at 8 MHz, with a factor 2 of margin, and two samples: the
    STT's wait for the next sample boundary, and one of slack, since the generator completes
    within the plan's continuous time); False also when STT would refuse them."""
    if exp.target is None:
        return True
    v, a = _bend32(VELOCITY, bend.to_chip), _bend32(ACCEL, bend.to_chip)
    target = _target(bend, exp)
    return not (v > 0x3FFFFFFF or a > 0x3FFFFFFF or abs(target) > 0x3FFFFFFF
                or plan(target, v, a).seconds(NOMINAL_CLOCK_HZ, margin_samples=2) * 1e6
                > MOVE_WAIT_US / 2)


def _explains(bend: Miswiring, readings: Sequence[Reading],
              experiments: dict[str, Experiment]) -> int | None:
    """How many readings ``bend`` predicts, all of them right; None: it gets one wrong."""
    checked = 0
    for r in readings:
        p = _predict(bend, r, experiments.get(r.experiment))
        if p is None:
            continue
        if not p(r.got):
            return None
        checked += 1
    return checked


def suspects_of_data_bus() -> list[tuple[str, Miswiring]]:
    """Every single wrong wire, with its ``wiring=`` name: stuck low, stuck high or open (the
    same to the logic), swapped with another line."""
    out = [(f"d{i}-low", Miswiring.parse(f"d{i}-low")) for i in range(8)]
    out += [(f"d{i}-high", Miswiring.parse(f"d{i}-high")) for i in range(8)]
    out += [(f"d{i}-d{j}", Miswiring.parse(f"d{i}-d{j}")) for i in range(8)
            for j in range(i + 1, 8)]
    return out


# ---------------------------------------------------------------------- messages
def _where(adapter: str, line: str) -> str:
    return f"LM629 {line} (pin {pin_of(line)})"


def _message(adapter: str, name: str) -> list[Suspect]:
    parts = name.split("-")
    a = f"D{parts[0][1]}"
    if parts[1] == "low":
        return [Suspect(a, f"{_where(adapter, a)} reads 0 always: check the wire to "
                           f"{adapter_pin(adapter, a)} (a short to GND or to a line held low)")]
    if parts[1] == "high":
        busy = (f"; busy never clears, which a chip without its clock (CLK pin {pin_of('CLK')}) "
                "shows the same way") if a == "D0" else ""
        return [Suspect(a, f"{_where(adapter, a)} reads 1 always: check the wire to "
                           f"{adapter_pin(adapter, a)} (missing or broken: the line floats high; "
                           f"or a short to +5 V){busy}")]
    b = f"D{parts[1][1]}"
    return [Suspect(x, f"{_where(adapter, x)} carries {y}'s bit: the wires of {a} and {b} are "
                       f"swapped: {x} must go to {adapter_pin(adapter, x)}")
            for x, y in ((a, b), (b, a))]


# ---------------------------------------------------------------------- the experiments
def _reset(chip: LM629, p: Program) -> Program:
    """/RST where the adapter has the line, even on an axis of a multi-axis board: /RST is
    shared, so every chip on the bus is reset (and left reset) by the check; the RESET command
    would itself cross the wires under test."""
    if chip.transport.has_reset_line:
        return p.reset()
    return p.command(Cmd.RESET)


def _unhurried(program: Program) -> Program:
    """``program`` with a wait longer than the chip's longest busy (100 us) before every
    transfer: a fault that hides the busy bit (D0 low, or swapped with a line that reads 0)
    must not make the host write while the chip is busy, or the experiment would read what
    the adapter's timing leaves, not what the wire does."""
    out = Program(busy_timeout_s=program.busy_timeout_s, top_select=program.top_select)
    for op in program.ops:
        if op.op in (Op.COMMAND, Op.WRITE, Op.READ, Op.SYNC):
            out.wait(UNHURRIED_US)
        out.ops.append(op)
    return out


def _run(chip: LM629, program: Program
         ) -> tuple[tuple[int, ...], tuple[int, ...], bool | None, LM629Error | None]:
    """Run one experiment: (statuses, words, HI, None), or empty results and the error that
    ended it (a bent wire may fail any program: that is a reading too)."""
    try:
        r = chip.run(_unhurried(program))
    except LM629Error as exc:
        return (), (), None, exc
    return r.statuses, r.words, r.hi, None


def _ltrj(p: Program, target: int) -> Program:
    p.command(Cmd.LTRJ).write(LTRJ_FULL).write32(ACCEL).write32(VELOCITY).write32(target)
    return p.command(Cmd.STT).wait(MOVE_WAIT_US)


def run_experiments(chip: LM629) -> tuple[list[Reading], dict[str, Experiment], list[bool], int]:
    """Every experiment, each from a fresh /RST; the chip is left reset.  Returns the readings,
    the experiments by name, the HI line after each program that reads it, and how far the
    shaft turned in all (RDRP at the end of each move experiment: counts since its /RST, which
    zeroes the real position; meaningful when the data lines pass)."""
    readings: list[Reading] = []
    hi: list[bool] = []
    exps: dict[str, Experiment] = {}
    travel: list[int] = []

    def add(exp_name: str, what: str, expected: frozenset[int], got: int | None,
            error: LM629Error | None, size: int = 1) -> None:
        text = f"{type(error).__name__}: {error}".split("\n")[0] if error is not None else ""
        readings.append(Reading(what, expected, got, text, exp_name, size, error))

    # 1. the read path: /RST, status at once, 1.5 ms later, twice
    st, _, h, err = _run(chip, _reset(chip, chip.program()).status().wait(RESET_WAIT_US)
                         .status().status())
    got = list(st) + [None] * (3 - len(st))
    if chip.transport.has_reset_line:
        add("", "status at once after /RST", AT_RESET, got[0], err)
    add("", "status 1.5 ms after /RST", RESET_DONE, got[1], err)
    add("", "status 1.5 ms after /RST (again)", RESET_DONE, got[2], err)
    if h is not None:
        hi.append(h)
    # 2. RSTI 0000: 80 or C0
    exps["rsti"] = Experiment("rsti", (int(Cmd.RSTI),), (0,))
    st, _, h, err = _run(chip, _reset(chip, chip.program()).wait(RESET_WAIT_US)
                         .command(Cmd.RSTI).write(0).sync())
    add("rsti", "status after RSTI 0000", CLEARED, st[0] if st else None, err)
    if h is not None:
        hi.append(h)
    # 3. reads and a write that need no move: RDDP (0 after /RST), RDSIGS, SBPA 0 (the
    # breakpoint /RST sets): their command bytes differ from LTRJ's and RSTI's where the
    # faults that turn those into other commands differ
    exps["reads"] = Experiment("reads", (int(Cmd.RDDP), int(Cmd.RDSIGS), int(Cmd.SBPA)), (0,))
    st, w, _, err = _run(chip, _reset(chip, chip.program()).wait(RESET_WAIT_US)
                         .command(Cmd.RDDP).read(2).sync().command(Cmd.RDSIGS).read(1).sync()
                         .command(Cmd.SBPA).write(0).write(0).sync())
    sts = list(st) + [None] * (3 - len(st))
    # (with the motor off the desired position follows the real one, which a load may turn:
    # any value; the reading is there for the command byte 08, which only RDDP has)
    add("reads", "RDDP after /RST", frozenset(), (w[0] << 16 | w[1]) if len(w) > 1 else None,
        err, size=4)
    add("reads", "status after RDDP", RESET_DONE, sts[0], err)
    add("reads", "RDSIGS after /RST", SIGNALS_AFTER_RESET, w[2] if len(w) > 2 else None, err,
        size=2)
    add("reads", "status after RDSIGS", RESET_DONE, sts[1], err)
    add("reads", "status after SBPA 00000000", RESET_DONE, sts[2], err)
    # 4. SBPA 00000000 alone after /RST: the one command with bit 5 and not bit 3 (D3 stuck
    # low leaves it alone and breaks RDDP above; D3 swapped with D5 turns it into RDDP)
    exps["sbpa"] = Experiment("sbpa", (int(Cmd.SBPA),), (0,))
    st, _, _, err = _run(chip, _reset(chip, chip.program()).wait(RESET_WAIT_US)
                         .command(Cmd.SBPA).write(0).write(0).sync())
    add("sbpa", "status after SBPA 00000000 alone", RESET_DONE, st[0] if st else None, err)
    # 5. the patterns, and the relative move
    for target, relative in [(p, None) for p in PATTERNS] + [RELATIVE]:
        name = f"{target:08X}" + (f"+{relative:08X}" if relative is not None else "")
        cmds = (int(Cmd.LTRJ), int(Cmd.STT), int(Cmd.RDDP))
        words: tuple[int, ...] = (LTRJ_FULL,) + ((LTRJ_RELATIVE,) if relative is not None else ())
        exps[name] = Experiment(name, cmds, words, target, relative)
        p = _ltrj(_reset(chip, chip.program()).wait(RESET_WAIT_US), target)
        if relative is not None:
            # the second STT no sooner than AN-706 4.6.2's 10 ms after the first
            p.wait(UPDATE_WAIT_US - MOVE_WAIT_US)
            p.command(Cmd.LTRJ).write(LTRJ_RELATIVE).write32(relative).command(Cmd.STT) \
                .wait(MOVE_WAIT_US)
        p.status().command(Cmd.RDDP).read(2).command(Cmd.RDRP).read(2)
        st, w, _, err = _run(chip, p)
        if len(w) == 4:  # the real position since this experiment's /RST zeroed it
            travel.append(abs(_signed32(w[2] << 16 | w[3])))
        add(name, f"status after the move to {name}", MOVED, st[0] if st else None, err)
        value = (w[0] << 16 | w[1]) if len(w) >= 2 else None
        want = (target + (relative or 0)) & 0xFFFFFFFF
        add(name, f"RDDP after the move to {name}", frozenset({want}), value, err, size=4)
    # the end: motor off, the chip left reset
    _run(chip, _reset(chip, chip.program()).wait(RESET_WAIT_US).status())
    return readings, exps, hi, sum(travel)


def _control_suspects(adapter: str, readings: list[Reading], hi: list[bool],
                      axis: int = 0) -> list[Suspect]:
    """What the readings say about /CS, /RD, /RST, the clock and HI when no data line does."""
    got = [r.got for r in readings if r.got is not None]
    name = adapter_name(adapter)
    out: list[Suspect] = []
    if got and all(g in (0xFF, 0xFFFFFFFF) for g in got):
        out.append(Suspect("/CS", "every read is FF: no chip drives the bus: check /CS (pin "
                           f"{pin_of('/CS')}) to {adapter_pin(adapter, '/CS', axis)}, /RD (pin "
                           f"{pin_of('/RD')}) to {adapter_pin(adapter, '/RD')}, the chip's supply "
                           f"(VDD pin {pin_of('VDD')}, GND pin {pin_of('GND')}) and its clock "
                           f"(CLK pin {pin_of('CLK')})"))
        return out
    by_what = {r.what: r for r in readings}
    first = by_what.get("status at once after /RST")
    done = by_what.get("status 1.5 ms after /RST")
    if done is not None and done.got == 0x00 and (first is None or first.got == 0x00):
        out.append(Suspect("/RST", f"the chip stays in reset (status 00 1.5 ms after /RST): "
                           f"check /RST (pin {pin_of('/RST')}) to {adapter_pin(adapter, '/RST')} "
                           f"and its pull-up, and the clock (CLK pin {pin_of('CLK')})"))
    elif first is not None and first.got is not None and first.got != 0x00 and done is not None \
            and done.got is not None and done.got & 0x01 == 0:
        out.append(Suspect("/RST", f"the status after /RST reads {first.got:02X}, not 00: the "
                           f"pulse does not reach the chip: check /RST (pin {pin_of('/RST')}) to "
                           f"{adapter_pin(adapter, '/RST')}"))
    if any(isinstance(r.exception, BusyTimeout) for r in readings):
        out.append(Suspect("busy", "busy never clears (status bit 0 stays 1): check the chip's "
                           f"clock (CLK pin {pin_of('CLK')}) and LM629 D0 (pin {pin_of('D0')}) "
                           f"to {adapter_pin(adapter, 'D0')}"))
    if not out and len(hi) >= 2 and hi[0] == hi[1]:
        state = "1" if hi[0] else "0"
        out.append(Suspect("HI", f"LM629 HI (pin {pin_of('HI')}) reads {state} always (high "
                           "after reset, low after RSTI expected): check the wire to "
                           f"{adapter_pin(adapter, 'HI')}"))
    if not out:
        bad = [r for r in readings if not r.ok()]
        for r in bad:
            diff = 0
            if r.got is not None:
                base = min(r.expected, key=lambda e: bin(e ^ r.got).count("1"))  # type: ignore[operator]  # got is not None here
                x = base ^ r.got
                diff = (x | x >> 8 | x >> 16 | x >> 24) & 0xFF
            lines = ", ".join(f"D{i} (pin {pin_of(f'D{i}')}, {name} "
                              f"{adapter_pin(adapter, f'D{i}').split(' ', 1)[1]})"
                              for i in range(8) if diff >> i & 1)
            extra = f": differs on {lines}" if lines else ""
            out.append(Suspect("?", f"{r.describe()}{extra}"))
    return out


def _alike(fault: str, variant: str, readings: Sequence[Reading]) -> int:
    """How many of ``readings`` a simulated bench wired with ``fault`` reads the same
    (:mod:`.wiring_reference`, made from the chip model; matched by what was read, so that a
    bench without a /RST line, which skips a reading, is compared reading for reading)."""
    ref = dict(zip(WHAT, READINGS.get(variant, READINGS["lm629"])[fault]))
    return sum(r.what in ref and ref[r.what] == r.got for r in readings)


def diagnose(adapter: str, readings: list[Reading], experiments: dict[str, Experiment],
             hi: Sequence[bool] = (), variant: str = "lm629", axis: int = 0) -> WiringReport:
    """The suspects that explain the readings (see the module docstring)."""
    report = WiringReport(adapter, list(readings), hi_seen=list(hi))
    if _explains(Miswiring(), readings, experiments) is not None:
        if len(hi) >= 2 and hi[0] == hi[1]:
            report.suspects = _control_suspects(adapter, readings, list(hi), axis)
        return report
    scored = [(n, _explains(b, readings, experiments)) for n, b in suspects_of_data_bus()]
    possible = [(n, k) for n, k in scored if k is not None]
    # Among the wires the spec-based rules allow, the ones whose simulated bench (the chip
    # model's reaction to the commands the fault made of others) reads most like this one;
    # then the ones that explain the most readings (a stuck line that turns every command
    # into another is consistent with anything, and explains little)
    alike = {n: _alike(n, variant, readings) for n, _ in possible}
    top = max(alike.values(), default=0)
    found = [(n, k) for n, k in possible if alike[n] == top]
    best = max((k for _, k in found), default=None)
    found = [(n, k) for n, k in found if k == best]
    if found:
        for n, _ in found:
            report.suspects += _message(adapter, n)
        if len(found) > 1:
            report.suspects.insert(0, Suspect("?", f"{len(found)} wires explain what was read "
                                              "(one of them, or several):"))
        return report
    report.suspects = _control_suspects(adapter, readings, list(hi), axis)
    return report


def adapter_for(url: str | PortURL) -> str:
    """The adapter a port URL drives: the FT232H for ``ftdi://`` and ``sim+ftdi://``, the
    Uno bridge otherwise (``sim://`` models the same bus)."""
    scheme = scheme_of(url)
    return "ft232h" if scheme in ("ftdi", "sim+ftdi") else "uno"


def check_wiring(chip: LM629, adapter: str | None = None) -> WiringReport:
    """Run the experiments on ``chip`` and name the suspect wires (nothing moves; the chip is
    left reset)."""
    adapter = adapter or adapter_for(chip.transport.url)
    readings, exps, hi, travel = run_experiments(chip)
    axis = chip.axis or 0
    if not any(c.chip_line == "HI" and c.chip == axis
               for c in connections(adapter, MAX_AXES[adapter])):
        hi = []  # this chip has no HI line on this adapter (its status is read instead)
    report = diagnose(adapter, readings, exps, hi, chip.variant, axis)
    report.travel = travel if report.passed else None
    return report


def wiring_suspects(chip: LM629) -> list[str]:
    """The suspect lines of a wiring check on ``chip`` (empty: every line passed, or the check
    could not run: its error is then the one line), for bring-up and doctor."""
    try:
        report = check_wiring(chip)
    except LM629Error as exc:
        return [f"the wiring check could not run: {exc}"]
    return [] if report.passed else report.lines()


__all__ = ["wiring_suspects", "Reading", "Suspect", "WiringReport", "adapter_for", "check_wiring", "diagnose",
           "run_experiments", "suspects_of_data_bus"]
