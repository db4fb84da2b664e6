"""``Move.wait`` with the far side doing the waiting: the end of a move seen one exchange after
it happens, not after many polls.

Where the transport can wait for a status bit inside a program (``transport.far_waits``: a
bridge with WAIT_STATUS), each exchange of the wait is one program:

* while the trajectory runs: WAIT_STATUS for trajectory complete, position error or motor off,
  for at most ``rules.poll`` (so the move's rules still get a snapshot every poll while it
  runs: stall, runaway), then a snapshot.  When the trajectory completes, the bridge sees it
  within its 125 us status poll and the snapshot follows in the same exchange;
* once it has completed, the settle check: snapshots ``rules.poll`` apart on the far side
  (WAITs between them) spanning what the settle rule still needs (``settle_time``, or its
  rest when the shaft was already at rest): the samples the polling loop would have taken, in
  one exchange.  A shaft at rest in all of them, within the tolerance, is done.  Where two
  checks are more than three polls apart (115200 baud: a check's program and reply take ~20 ms),
  rest is never judged across them (a shaft turning round reads the same twice, far apart):
  each check then spans all of ``settle_time`` by itself.

Every snapshot is fed to the same :class:`~lm629_host.chip.move.MoveWatch`, so the rules (stall,
runaway, settle, following error, timeout) are exactly those of the polling loop.  The
snapshots of a settle check are timed back from the last one, ``rules.poll`` apart: the far
side's WAIT never ends early, so the span the shaft was seen at rest is at least that (never
overstated).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol

from lm629_host.chip.move import Move, MoveResult, MoveWatch
from lm629_host.bus.opcodes import Status
from lm629_host.bus.program import Program, ProgramResult
from lm629_host.bus.snapshot import Snapshot, add_snapshot, snapshot_at

#: what ends a far-side wait early: the move's end, or a fault the chip flags
END_MASK = Status.TRAJECTORY_COMPLETE | Status.POSITION_ERROR | Status.MOTOR_OFF
#: the longest far-side WAIT a program carries (16 bits of microseconds)
WAIT_MAX_US = 0xFFFF
#: two snapshots at most this many polls apart are judged as consecutive, as the polling loop
#: judges its own: behind an Uno it leaves a poll, a 4.096 ms flush tick and the request between
#: two (9-13 ms at a 5 ms poll); a 1 Mbaud link ~8 ms between two checks; 115200 baud ~24 ms
COARSE_POLLS = 3
#: the most snapshots one settle check reads (9 words each: 108 words, within what a bridge's
#: reply carries)
SETTLE_SNAPSHOTS_MAX = 12


class FarWaitChip(Protocol):
    def program(self) -> Program: ...

    def clearing_wrap(self, program: Program) -> Program: ...

    def run(self, program: Program) -> ProgramResult: ...

    def extended(self, s: Snapshot) -> Snapshot: ...


def wait_far(move: Move, watch: MoveWatch,
             progress: Callable[[Snapshot], None] | None) -> MoveResult:
    """The loop of :meth:`Move.wait` with the far side waiting (see the module doc)."""
    chip: FarWaitChip = move.chip  # type: ignore[assignment]  # only LM629.move_to sets wait_far, with itself
    clock = move.chip.clock
    rules = watch.rules
    chunk_ms = max(1, round(rules.poll * 1e3))
    poll_us = round(rules.poll * 1e6)
    n = math.ceil(rules.settle_time / rules.poll - 1e-9) + 1  # snapshots spanning settle_time
    settle = poll_us <= WAIT_MAX_US and n <= SETTLE_SNAPSHOTS_MAX
    coarse = False  # the last settle check found the gap to the one before it too wide
    while True:
        if watch.complete_at is None or not settle:
            # a wraparound bit seen is cleared as the polling loop's snapshots clear it
            p = chip.clearing_wrap(chip.program()).wait_status(int(END_MASK), chunk_ms)
            r = chip.run(add_snapshot(p))
            snaps = [chip.extended(snapshot_at(r, 0, clock.now(), status_at=1))]
            first_of_check = False
        else:
            # as many snapshots as the settle rule still needs: all of them, or (the shaft at
            # rest since quiet_since, or from the last snapshot read on) the rest of
            # settle_time, so that the end is seen at the poll the polling loop would see it
            since = watch.prev.time if watch.quiet_since is None else watch.quiet_since
            left = rules.settle_time - (watch.prev.time - since)
            k_n = n if coarse else max(1, min(n, math.ceil(left / rules.poll - 1e-9)))
            p = chip.clearing_wrap(chip.program()).wait(poll_us)
            add_snapshot(p)
            for _ in range(k_n - 1):
                add_snapshot(p.wait(poll_us))
            r = chip.run(p)
            now = clock.now()
            snaps = [chip.extended(snapshot_at(r, k, now - (k_n - 1 - k) * rules.poll))
                     for k in range(k_n)]
            # a link whose exchanges leave more than COARSE_POLLS polls between the last
            # snapshot of one check and the first of the next (115200 baud, long programs:
            # ~24 ms) cannot show a shaft at rest across them (a shaft turning round reads the
            # same twice, far apart): then rest is counted inside each check alone, all of
            # settle_time in one
            coarse = snaps[0].time - watch.prev.time > COARSE_POLLS * rules.poll
            first_of_check = coarse
        for i, s in enumerate(snaps):
            if first_of_check and i == 0:
                watch.restart_rest(s)  # rest counted from this snapshot on, not across exchanges
            if progress is not None:
                progress(s)
            result = watch.check(s)
            if result is not None:
                return result


__all__ = ["END_MASK", "wait_far"]
