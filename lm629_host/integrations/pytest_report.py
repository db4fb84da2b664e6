"""The pytest plugin's failure report: the test's last bus programs decoded, one a line, and
the text of a chip snapshot (:class:`~lm629_host.integrations.pytest_guard.Bench` keeps the
programs and reads the snapshots)."""

from __future__ import annotations

import enum
from dataclasses import dataclass

from lm629_host.bus.opcodes import COMMANDS, Cmd, Direction, Status
from lm629_host.bus.program import STATUS_OPS, BusOp, Op, ProgramResult
from lm629_host.bus.snapshot import Snapshot

#: how many lines of bus programs the failure report keeps (a run of identical programs is
#: one line)
TRACE_PROGRAMS = 40
#: the commands that only read the chip: a program of these alone changes nothing in it
READ_COMMANDS = frozenset(int(c) for c, info in COMMANDS.items()
                          if info.direction is Direction.READ)


@dataclass
class Run:
    """One bus program of the test, as the failure report shows it, or a run of identical
    ones (``count``: from ``time`` to ``last``)."""

    time: float  #: the transport's clock when it ended
    ops: tuple[BusOp, ...]
    result: ProgramResult | None  #: None: it raised
    error: str = ""
    count: int = 1
    last: float = 0.0

    @property
    def changes_chip(self) -> bool:
        """True when the program may have changed the chip (anything but status reads and
        data-reporting commands: LFIL, LTRJ, STT, a reset...)."""
        return any(o.op is Op.RESET or (o.op is Op.COMMAND and o.arg not in READ_COMMANDS)
                   for o in self.ops)


class ProgramLog:
    """The last bus programs of a test, for its failure report: a program identical to the one
    before it (same operations, same answers) is counted on that line, and when the log is
    full the oldest program that only read the chip goes first, so that the commands that
    set a move up (LFIL, LTRJ, STT) stay in view behind any number of wait polls."""

    def __init__(self, lines: int = TRACE_PROGRAMS) -> None:
        self.lines = lines
        self.runs: list[Run] = []
        self.dropped = 0  #: programs no longer shown

    def add(self, run: Run) -> None:
        runs = self.runs
        if runs:
            prev = runs[-1]
            if prev.ops == run.ops and prev.result == run.result and prev.error == run.error:
                prev.count += 1
                prev.last = run.time
                return
        runs.append(run)
        if len(runs) > self.lines:
            gone = next((k for k, r in enumerate(runs) if not r.changes_chip), 0)
            self.dropped += runs.pop(gone).count

    def text_lines(self) -> list[str]:
        out = [f"  ({self.dropped} older program(s) not shown: those that only read the chip "
               "go first)"] \
            if self.dropped else []
        for r in self.runs:
            line = f"  {r.time * 1e3:12.4f}  {program_text(r)}"
            if r.count > 1:
                line += f"  (x{r.count}, the last at {r.last * 1e3:.4f})"
            out.append(line)
        return out


def program_text(run: Run) -> str:
    """``cs0: LTRJ 0008 0004 0000; STT; sync C0 (BREAKPOINT|MOTOR_OFF)``: one program decoded."""
    words = iter(run.result.words if run.result else ())
    statuses = iter(run.result.statuses if run.result else ())
    parts: list[str] = []
    chip = 0
    for o in run.ops:
        op = o.op
        if op is Op.COMMAND:
            try:
                parts.append(Cmd(o.arg).name)
            except ValueError:
                parts.append(f"command {o.arg:02X}")
        elif op is Op.WRITE:
            parts[-1:] = [(parts[-1] if parts else "write") + f" {o.arg:04X}"]
        elif op is Op.READ:
            w = next(words, None)
            text = f"{w:04X}" if w is not None else "????"
            if parts and "<-" in parts[-1]:
                parts[-1] += f" {text}"
            else:
                parts[-1:] = [(parts[-1] if parts else "read") + f" <- {text}"]
        elif op in STATUS_OPS:
            st = next(statuses, None)
            name = {Op.STATUS: "status", Op.SYNC: "sync"}.get(op, f"wait for {o.arg >> 16:02X}")
            parts.append(f"{name} {status_text(st)}")
        elif op is Op.RESET:
            parts.append("/RST")
        elif op is Op.WAIT:
            parts.append(f"wait {o.arg} us")
        elif op is Op.SELECT:
            chip = o.arg
            parts.append(f"cs{chip}:")
    if not run.ops or run.ops[0].op is not Op.SELECT:
        parts.insert(0, "cs0:")  # a program starts on chip 0
    text = "; ".join(parts).replace(":;", ":")
    result = run.result
    if result is not None and result.status is not None and (
            not result.statuses or result.statuses[-1] != result.status):
        text += f"  [status {status_text(result.status)}]"
    if run.error:
        text += f"  !! {run.error.splitlines()[0][:160]}"
    return text


def status_text(status: int | None) -> str:
    if status is None:
        return "??"
    return f"{status:02X} ({flag_names(Status, status)})"


def flag_names(flags: type[enum.Flag], value: int) -> str:
    names = [f.name for f in flags if value & f.value]
    return "|".join(n for n in names if n) or "none"


def snapshot_line(s: Snapshot, chip_select: int) -> str:
    """One chip's snapshot as the report shows it: status, signals, positions, velocities."""
    return (f"chip snapshot cs{chip_select} at t={s.time * 1e3:.4f} ms: status {int(s.status):02X} "
            f"({flag_names(Status, int(s.status))}), signals {int(s.signals):04X} "
            f"({flag_names(type(s.signals), int(s.signals))}), desired position "
            f"{s.desired_position}, real position {s.real_position}, following error "
            f"{s.following_error}, desired velocity {s.desired_velocity / 65536:.4f} counts/sample, "
            f"real velocity {s.real_velocity} counts/sample, integration sum {s.integration_sum}")
