"""Recordings timed where the chip is: :meth:`LM629.record <lm629_host.LM629.record>` ->
:class:`Trace`, and :meth:`LM629.record_stream <lm629_host.LM629.record_stream>` for live views.

Why: a host that polls across USB samples when the adapter lets it (an Uno's 16U2 passes a
reply on at its 4.096 ms flush tick), so host-polled traces jitter by milliseconds and are
slow.  Here the transport runs a *sample program* (a status read and data-reporting commands,
nothing that changes the chip) every period on its far side and stamps each row with the far
side's clock: the bridge's timer (RECORD, ``firmware_bridge/PROTOCOL.md``), the simulator's
clock on ``sim://``.  Latency then changes only when the rows arrive.  Where a transport
cannot (the FT232H, a bridge before firmware 1.3) the host polls and says so
(:attr:`Trace.far_side`, :meth:`~lm629_host.transports.base.Transport.record_note`).

A row lost on a faulty link is a *gap*: its index is missing from :attr:`Trace.rows`
(:attr:`Trace.missing`, :attr:`Trace.gaps`), never a value made up.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator, Iterator
from dataclasses import dataclass, field, replace
from typing import Protocol

from lm629_host.bridge.protocol.constants import FAST_BAUD
from lm629_host.errors import ArgumentError, LM629Error, TransportError
from lm629_host.bus.opcodes import Cmd, Signals, Status, s32_words
from lm629_host.physics.pid import sample_period_s
from lm629_host.bus.program import Program
from lm629_host.bus.snapshot import SNAPSHOT_READS, Snapshot, add_snapshot, snapshot_of
from lm629_host.transports.base import Transport
from lm629_host.transports.reports import RawRow

#: the columns of a row: the basic ones (status, RDDP, RDRP), or a whole snapshot's
BASIC_READS = ((Cmd.RDDP, 2), (Cmd.RDRP, 2))
FULL_READS = SNAPSHOT_READS


class RecordingChip(Protocol):
    """What a recording needs of its chip (an :class:`~lm629_host.LM629`)."""

    transport: Transport

    @property
    def clock_hz(self) -> float: ...  # the chip's clock: one sample every 2048 clocks

    def program(self) -> Program: ...


def sample_program(chip: RecordingChip, full: bool = False) -> Program:
    """The program run for each row: the status byte, then RDDP and RDRP (``full``: every
    register a :class:`~lm629_host.bus.snapshot.Snapshot` holds)."""
    return add_snapshot(chip.program(), FULL_READS if full else BASIC_READS)


@dataclass(frozen=True)
class Row:
    """One sample.  ``t``: seconds from the recording's first row, on the clock that timed it;
    ``index``: its slot (``t`` is about ``index`` periods).  The velocity, signal and
    integration columns are None unless the recording was ``full``."""

    index: int
    t: float
    status: Status
    desired: int  #: RDDP, counts
    real: int  #: RDRP, counts
    signals: Signals | None = None
    desired_velocity: int | None = None  #: RDDV, signed 16.16
    real_velocity: int | None = None  #: RDRV, counts/sample
    integration_sum: int | None = None  #: RDSUM

    @property
    def following_error(self) -> int:
        return self.desired - self.real

    def snapshot(self, t0: float = 0.0) -> Snapshot:
        """This row as a :class:`Snapshot` at ``t0 + t`` (unrecorded columns as 0)."""
        return Snapshot(self.status, self.signals if self.signals is not None else Signals(0),
                        self.desired, self.real, self.desired_velocity or 0,
                        self.real_velocity or 0, self.integration_sum or 0, t0 + self.t)


def _row(raw: RawRow, t: float, full: bool) -> Row:
    w, st = raw.words, raw.statuses
    if full:
        s = snapshot_of(st[0], w, t)
        return Row(raw.index, t, s.status, s.desired_position, s.real_position, s.signals,
                   s.desired_velocity, s.real_velocity, s.integration_sum)
    return Row(raw.index, t, Status(st[0]), s32_words(w[0], w[1]), s32_words(w[2], w[3]))


@dataclass
class Trace:
    """A finished recording: its rows in order, and what is missing."""

    period_s: float
    rows: list[Row] = field(default_factory=list)
    #: rows asked for (0: until stopped)
    asked: int = 0
    #: True when the rows were timed where the chip is (the bridge's timer, a simulator)
    far_side: bool = True
    #: the first row's time on the clock that timed it (``t`` counts from here)
    t0: float = 0.0

    def __len__(self) -> int:
        return len(self.rows)

    def __iter__(self) -> Iterator[Row]:
        return iter(self.rows)

    @property
    def t(self) -> list[float]:
        return [r.t for r in self.rows]

    @property
    def status(self) -> list[Status]:
        return [r.status for r in self.rows]

    @property
    def desired(self) -> list[int]:
        return [r.desired for r in self.rows]

    @property
    def real(self) -> list[int]:
        return [r.real for r in self.rows]

    @property
    def following_error(self) -> list[int]:
        return [r.following_error for r in self.rows]

    @property
    def missing(self) -> list[int]:
        """The indices of rows that never arrived (lost on the link, or a period the host could
        not keep), from the first row asked up to the last one (``asked``) or the last one
        received."""
        have = {r.index for r in self.rows}
        end = self.asked if self.asked else (self.rows[-1].index + 1 if self.rows else 0)
        return [k for k in range(end) if k not in have]

    @property
    def gaps(self) -> list[tuple[int, int]]:
        """The missing rows as (first index, how many) runs."""
        out: list[tuple[int, int]] = []
        for k in self.missing:
            if out and out[-1][0] + out[-1][1] == k:
                out[-1] = (out[-1][0], out[-1][1] + 1)
            else:
                out.append((k, 1))
        return out


class RecordStream:
    """The rows of a recording as they arrive (``for row in stream``); ``close()`` (or the end
    of a ``with`` block) stops the far side.  :meth:`trace` collects what has come so far."""

    def __init__(self, chip: RecordingChip, period_s: float, rows: int, full: bool) -> None:
        self.period_s = period_s
        self.asked = rows
        self.full = full
        transport = chip.transport
        self._chip = chip
        self._host_loop = type(transport).record_rows is Transport.record_rows
        self.far_side = transport.records_on_far_side
        self.note = transport.record_note()
        self._program = sample_program(chip, full)
        self._raw: Iterator[RawRow] | None = None
        self._transport = transport
        self._t0: float | None = None
        self.rows: list[Row] = []
        # the chip's extended positions (AN-706 6.5.2): a recording across the register's
        # wraparound shows no jump; None for a chip without them
        self._extend: Callable[[Snapshot], Snapshot] | None = getattr(chip, "extended", None)

    def __iter__(self) -> Iterator[Row]:
        if self._raw is None:
            self._raw = self._transport.record_rows(self._program, self.period_s, self.asked)
        for raw in self._rows(self._raw):
            if self._t0 is None:
                self._t0 = raw.t
            row = _row(raw, raw.t - self._t0, self.full)
            if self._extend is not None:
                s = self._extend(row.snapshot())
                row = replace(row, desired=s.desired_position, real=s.real_position)
            self.rows.append(row)
            yield row

    def _rows(self, raw: Iterator[RawRow]) -> Iterator[RawRow]:
        """``raw``, its program first shown to the chip's ``before_program`` as any of the
        chip's programs is (a host-timed shaped move issues a piece that is due:
        :class:`~lm629_host.chip.shapes.ShapedMove`): once, or before every row where the host
        runs the rows one by one (the transport's default loop; any other program would end a
        bridge's stream), so the pieces go out during the recording."""
        while True:
            hook = getattr(self._chip, "before_program", None)
            if hook is not None:
                hook(self._program)
            if not self._host_loop:
                yield from raw
                return
            try:
                row = next(raw)
            except StopIteration:
                return
            yield row

    def close(self) -> None:
        raw, self._raw = self._raw, None
        close = getattr(raw, "close", None)
        if close is not None:
            close()

    def __enter__(self) -> RecordStream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def trace(self) -> Trace:
        return Trace(self.period_s, list(self.rows), self.asked, self.far_side, self._t0 or 0.0)


#: rows in one recording at most: the bridge's RECORD counts them in 16 bits
MAX_ROWS = 0xFFFF


def _seconds(value: object) -> float | None:
    """``value`` as seconds when it is a finite real number (not a bool), else None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value) if math.isfinite(value) else None


def check_period(period_s: object) -> float:
    """``period_s`` a finite number of seconds above 0, else an :class:`ArgumentError`."""
    period = _seconds(period_s)
    if period is None or period <= 0:
        raise ArgumentError("period_s", period_s, f"period_s={period_s!r} must be a finite "
                            "number of seconds above 0")
    return period


def rows_for(period_s: float, duration_s: float | None) -> int:
    """Rows of a recording of ``duration_s`` (None: until stopped, 0); ``duration_s`` a finite
    number of seconds from one period to 65535 periods, else an :class:`ArgumentError` naming
    that range (``period_s`` checked first)."""
    period = check_period(period_s)
    if duration_s is None:
        return 0
    duration = _seconds(duration_s)
    hi = MAX_ROWS * period
    if duration is None or not period <= duration <= hi:
        raise ArgumentError(
            "duration_s", duration_s,
            f"duration_s={duration_s!r} must be a finite number of seconds in "
            f"{period:g}..{hi:g} (one period_s={period:g} up to {MAX_ROWS} rows; "
            "record_stream without a duration runs until closed)", lo=period, hi=hi)
    return max(1, min(MAX_ROWS, round(duration / period)))


def open_stream(chip: RecordingChip, period_s: float, duration_s: float | None = None, *,
                full: bool = False) -> RecordStream:
    """Check the request (:class:`ArgumentError`, a ``ValueError``, before any traffic) and
    make the stream."""
    rows = rows_for(period_s, duration_s)
    sample = sample_period_s(chip.clock_hz)
    if period_s < sample * (1 - 1e-9):
        # the chip's registers change once a sample: a shorter period would repeat rows, and
        # the rows that a sample boundary skips would read as lost
        raise ArgumentError("period_s", period_s,
                            f"period_s={period_s:g} is below the chip's sample time "
                            f"{sample * 1e6:g} us (2048 clocks at {chip.clock_hz / 1e6:g} MHz): "
                            "its positions change once a sample, so record at least that "
                            "far apart", lo=sample)
    program = sample_program(chip, full)
    top = chip.transport.record_max_rate(program)
    if top is not None and 1.0 / period_s > top:
        # a faster line is advice only where the line is not already at the fastest rate
        baud = getattr(chip.transport, "baud", None)
        faster = "a faster line (fast_baud=1000000) or " if baud is None or baud < FAST_BAUD else ""
        raise ValueError(
            f"period_s={period_s:g}: {1 / period_s:g} rows/s is more than "
            f"{chip.transport.describe()} carries; the highest rate is {math.floor(top)} rows/s "
            f"(period_s >= {1 / math.floor(top):.6g}); {faster}fewer columns carry more")
    return RecordStream(chip, period_s, rows, full)


def far_snapshots(chip: RecordingChip, period_s: float, rows: int = 0,
                  ) -> Generator[Snapshot, None, None] | None:
    """Snapshots every ``period_s`` (``rows`` of them, 0: until closed) recorded on the far
    side, for the CLI's ``watch`` and ``step`` and the tuner; None when the transport does not
    record on its far side or cannot carry the rate (the caller then polls from the host).  Their
    times are the transport clock when the recording began plus each row's far-side time."""
    transport = chip.transport
    if not transport.records_on_far_side:
        return None
    top = transport.record_max_rate(sample_program(chip, full=True))
    if top is not None and 1.0 / period_s > top:
        return None
    stream = RecordStream(chip, period_s, rows, True)
    start = transport.clock.now()

    def gen() -> Generator[Snapshot, None, None]:
        with stream:
            for row in stream:
                yield row.snapshot(start)
    return gen()


def record(chip: RecordingChip, period_s: float, duration_s: float, *,
           full: bool = False) -> Trace:
    """Record for ``duration_s`` (see :meth:`LM629.record <lm629_host.LM629.record>`): a
    finite duration (ArgumentError else: :meth:`LM629.record_stream` runs until closed).  A
    link that fails or goes silent before the last row raises, with the rows that came
    attached as the error's ``.trace``."""
    if duration_s is None:  # a number that is not finite: rows_for names the range
        raise ArgumentError("duration_s", duration_s,
                            f"duration_s={duration_s!r} must be a finite number of seconds "
                            "(record_stream(period_s) records until it is closed)")
    stream = open_stream(chip, period_s, duration_s, full=full)
    try:
        with stream:
            for _ in stream:
                pass
    except LM629Error as exc:
        # the rows so far ride on whichever error ended the recording (no error class has a
        # field for them, and mypy would refuse the plain attribute)
        setattr(exc, "trace", stream.trace())  # noqa: B010 - see above
        raise
    trace = stream.trace()
    last = trace.rows[-1].index if trace.rows else -1
    if last < stream.asked - 1:
        transport = chip.transport
        lost = TransportError(
            f"the recording ended after row {last} of {stream.asked}: nothing more came from "
            f"{transport.describe()} (the link failed or went silent); the {len(trace.rows)} "
            "rows that came are in this error's .trace", port=getattr(transport, "url", None))
        setattr(lost, "trace", trace)  # noqa: B010 - as above: TransportError has no trace field
        raise lost
    return trace


__all__ = ["BASIC_READS", "FULL_READS", "MAX_ROWS", "RecordStream", "Row", "Trace",
           "check_period", "far_snapshots", "open_stream", "record", "rows_for",
           "sample_program"]


class RecordingMixin:
    """:class:`~lm629_host.LM629`'s recordings: :func:`record` and :func:`open_stream`."""

    def record(self: RecordingChip, period_s: float, duration_s: float, *, full: bool = False) -> Trace:
        """Sample status, desired (RDDP) and real (RDRP) position every ``period_s`` for
        ``duration_s``, timed where the chip is: the bridge's own timer (rows stamped with its
        clock and streamed, so the link's latency changes nothing but when they arrive), the
        simulator's clock on ``sim://``; elsewhere the host polls
        (``transport.record_note()`` says which).  ``full``: every register of a snapshot.
        A rate the line cannot carry is a ``ValueError`` naming the highest it can, before
        any traffic.  A row lost on the link is a gap (``trace.missing``), never made up.
        See :mod:`lm629_host.chip.recording`."""
        self.transport.check_open()  # before the rate is judged: "closed", not "too fast"
        return record(self, period_s, duration_s, full=full)

    def record_stream(self: RecordingChip, period_s: float, duration_s: float | None = None, *,
                      full: bool = False) -> RecordStream:
        """The rows of :meth:`record` as they arrive (``duration_s=None``: until closed), for
        live views: ``with chip.record_stream(1e-3) as rows: for row in rows: ...``."""
        self.transport.check_open()
        return open_stream(self, period_s, duration_s, full=full)
