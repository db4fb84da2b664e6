"""A lossy link for the fault tests: a :class:`~lm629_host.bridge.protocol.Pipe` wrapper that drops,
corrupts, duplicates and delays bytes at configurable rates, from a seeded random generator.

It wraps any pipe (the in-process :class:`~lm629_host.sim.bridge.EmuPipe`, the simulated AVR
UART of ``sim+avr://``), in either direction or both, and counts what it did, so that a test
can prove that the faults happened and that the link still ran every command exactly once.
Delays are stalls of the byte stream on the pipe's own clock (order is kept, as on a real
serial line; a stall longer than the host's timeout looks like a lost reply that turns up late).
"""

from __future__ import annotations

import functools
import random
from collections import deque
from dataclasses import dataclass, field

from lm629_host.bridge.protocol.pipe import Pipe


@dataclass
class FaultCounts:
    """What the wrapper did to the bytes in one direction."""

    bytes: int = 0
    dropped: int = 0
    corrupted: int = 0
    duplicated: int = 0
    delayed: int = 0

    def __str__(self) -> str:
        return (f"{self.bytes} bytes: {self.dropped} dropped, {self.corrupted} corrupted, "
                f"{self.duplicated} duplicated, {self.delayed} delayed")


@dataclass
class FaultRates:
    """Per-byte probabilities of each fault (0..1), and the length of a delay."""

    drop: float = 0.0
    corrupt: float = 0.0
    duplicate: float = 0.0
    delay: float = 0.0
    delay_s: float = 0.02

    def __post_init__(self) -> None:
        for name in ("drop", "corrupt", "duplicate", "delay"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"{name}={v!r} is a per-byte probability: expected 0..1")
        if self.drop + self.corrupt + self.duplicate + self.delay > 1.0:
            raise ValueError("drop + corrupt + duplicate + delay must not exceed 1")
        if self.delay_s < 0:
            raise ValueError(f"delay_s={self.delay_s!r} must be >= 0")


@dataclass
class _Direction:
    rates: FaultRates
    counts: FaultCounts = field(default_factory=FaultCounts)


class FaultPipe:
    """``FaultPipe(inner, drop=..., corrupt=..., duplicate=..., delay=..., seed=...)``.

    ``to_bridge`` and ``to_host`` choose the directions the faults apply to (both by default).
    ``enabled`` can be switched off, e.g. for a clean handshake before a test.
    """

    def __init__(self, inner: Pipe, *, drop: float = 0.0, corrupt: float = 0.0,
                 duplicate: float = 0.0, delay: float = 0.0, delay_s: float = 0.02,
                 seed: int = 0, to_bridge: bool = True, to_host: bool = True) -> None:
        def rates() -> FaultRates:  # one object per direction, so each can be changed alone
            return FaultRates(drop, corrupt, duplicate, delay, delay_s)

        self.inner = inner
        self.clock = inner.clock
        self.rng = random.Random(seed)
        self.out = _Direction(rates() if to_bridge else FaultRates())
        self.into = _Direction(rates() if to_host else FaultRates())
        self.enabled = True
        self._pending_out: deque[tuple[float, bytes]] = deque()  # (release time, bytes)
        self._held_in: deque[tuple[float, bytes]] = deque()

    # ------------------------------------------------------------------ faults
    def _mangle(self, data: bytes, d: _Direction) -> list[tuple[float, bytes]]:
        """Segments (stall before it, bytes) after the faults."""
        r, c = d.rates, d.counts
        c.bytes += len(data)
        if not self.enabled:
            return [(0.0, bytes(data))]
        rng = self.rng
        segs: list[tuple[float, bytearray]] = [(0.0, bytearray())]
        p_drop, p_cor = r.drop, r.drop + r.corrupt
        p_dup, p_del = p_cor + r.duplicate, p_cor + r.duplicate + r.delay
        for b in data:
            x = rng.random()
            if x >= p_del:
                segs[-1][1].append(b)
            elif x < p_drop:
                c.dropped += 1
            elif x < p_cor:
                c.corrupted += 1
                segs[-1][1].append(b ^ rng.randrange(1, 256))
            elif x < p_dup:
                c.duplicated += 1
                segs[-1][1].extend((b, b))
            else:
                c.delayed += 1
                segs.append((r.delay_s, bytearray((b,))))
        return [(s, bytes(buf)) for s, buf in segs if buf or s]

    # ------------------------------------------------------------------ Pipe
    def write(self, data: bytes) -> None:
        t = self.clock.now()
        if self._pending_out:
            t = max(t, self._pending_out[-1][0])
        for stall, seg in self._mangle(data, self.out):
            t += stall
            if not self._pending_out and stall == 0.0:
                if seg:
                    self.inner.write(seg)
            else:
                self._pending_out.append((t, seg))

    def _release_out(self, now: float) -> None:
        q = self._pending_out
        while q and q[0][0] <= now:
            seg = q.popleft()[1]
            if seg:
                self.inner.write(seg)

    def read(self, timeout_s: float) -> bytes:
        clock = self.clock
        deadline = clock.now() + max(0.0, timeout_s)
        reached = 0.0  # the time an empty inner read waited up to (the clock may round below)
        while True:
            now = max(clock.now(), reached)
            self._release_out(now)
            held = self._held_in
            if held and held[0][0] <= now:
                out = bytearray()
                while held and held[0][0] <= now:
                    out += held.popleft()[1]
                if out:
                    return bytes(out)
                continue
            events = [deadline]
            if self._pending_out:
                events.append(self._pending_out[0][0])
            if held:
                events.append(held[0][0])
            until = min(events)
            data = self.inner.read(max(0.0, until - now))
            if data:
                t = clock.now()
                if held:
                    t = max(t, held[-1][0])
                first = True
                result = b""
                for stall, seg in self._mangle(data, self.into):
                    t += stall
                    if first and stall == 0.0 and not held:
                        result = seg
                    else:
                        held.append((t, seg))
                    first = False
                if result:
                    return result
                continue
            if until >= deadline:
                return b""
            reached = until

    def close(self) -> None:
        self.inner.close()

    def describe(self) -> str:
        return f"to bridge: {self.out.counts}; to host: {self.into.counts}"


# ---------------------------------------------------------------------------------- soak
@dataclass
class SoakResult:
    """Outcome of :func:`soak`: per call, the command record it should leave and whether it
    returned normally (certain) or raised a typed error (it may or may not have run)."""

    calls: int = 0
    ok: int = 0
    typed_errors: int = 0
    not_sent: int = 0  #: typed errors that say nothing was sent (certainly did not run)
    expected: list[tuple[tuple[int, tuple[int, ...]], bool]] = field(default_factory=list)


def soak(chip, n: int) -> SoakResult:
    """``n`` typed commands on ``chip`` (an :class:`~lm629_host.LM629`), alternately a unique
    SBPA breakpoint (its two words identify the call) and a real-position read that must read
    0 (the motor is at rest).  Typed errors are counted; any other exception propagates."""
    from lm629_host.errors import LM629Error
    from lm629_host.bus.opcodes import Cmd

    r = SoakResult()
    for i in range(n):
        r.calls += 1
        entry: tuple[int, tuple[int, ...]]
        if i % 2:
            pos = 1000 + i
            entry = (int(Cmd.SBPA), ((pos >> 16) & 0xFFFF, pos & 0xFFFF))
            call = functools.partial(chip.set_breakpoint, pos)
        else:
            entry = (int(Cmd.RDRP), ())
            call = chip.read_real_position
        try:
            value = call()
        except LM629Error as exc:
            # the link transport's LinkError says whether the request may have reached the chip
            may_have_run = getattr(exc, "may_have_run", None)
            if may_have_run is None:  # not the link's LinkError: not a link fault
                raise
            r.typed_errors += 1
            if may_have_run is False:  # nothing was sent: it must not be in the record
                r.not_sent += 1
            else:
                r.expected.append((entry, False))
        else:
            if entry[0] == Cmd.RDRP and value != 0:
                raise AssertionError(f"call {i}: read_real_position() returned {value}, not 0: "
                                     "a corrupted reply got through")
            r.ok += 1
            r.expected.append((entry, True))
    return r


Entry = tuple[int, tuple[int, ...]]


def check_record(history: list[Entry], expected: list[tuple[Entry, bool]]) -> tuple[int, int]:
    """Decide exactly whether the chip's record (``ChipModel.history``) is what the calls may
    have left: every call that returned normally there exactly once, every call that raised
    there once or not at all, nothing else, all in call order.

    The record cannot say *which* call a command came from when two calls send the same bytes
    (two RDRP), so a greedy left-to-right match is wrong: it may give the one RDRP in the record
    to an earlier call that failed and then call the later, successful one lost.  This is the
    exact test: "can ``history`` be made from the calls by leaving out only calls that raised?",
    solved by following every record position the calls so far can have reached (a set that
    stays small: a unique command, such as an SBPA with its own position, collapses it).

    Returns (failed calls that ran, failed calls that did not) for one consistent assignment;
    raises AssertionError naming the first call no assignment can explain.
    """
    n_hist = len(history)
    # reach: record position -> (previous position, this call ran) for the calls so far
    reach: dict[int, None] = {0: None}
    back: list[dict[int, tuple[int, bool]]] = []
    for i, (entry, certain) in enumerate(expected):
        step: dict[int, tuple[int, bool]] = {}
        for j in reach:
            if j < n_hist and history[j] == entry:
                step.setdefault(j + 1, (j, True))
            if not certain:
                step.setdefault(j, (j, False))
        if not step:
            lo, hi = min(reach), max(reach)
            raise AssertionError(
                f"call {i} {entry} returned normally but no way of running the calls before it "
                f"puts it in the chip's record (record positions {lo}..{hi} reachable: "
                f"{history[lo:hi + 3]}): a command was lost, repeated or run out of order")
        back.append(step)
        reach = dict.fromkeys(step)
    if n_hist not in reach:
        j = max(reach)
        raise AssertionError(f"the chip saw {n_hist - j} command(s) nobody sent, or one twice, "
                             f"or out of order: {history[j:j + 5]} (record position {j})")
    ran = lost = 0
    j = n_hist
    for (_entry, certain), step in zip(reversed(expected), reversed(back)):
        j, took = step[j]
        if not certain:
            ran += took
            lost += not took
    return ran, lost


__all__ = ["FaultCounts", "FaultPipe", "FaultRates", "SoakResult", "check_record", "soak"]
