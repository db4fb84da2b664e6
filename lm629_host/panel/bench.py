"""The bench behind ``lm629 panel``: one thread owns the board, samples it for the plots and
runs the page's commands between samples.

Why one thread: a bridge's far-side recording (RECORD) ends when any other program runs on
the link, and a command must never land between a sample program's cycles.  So the worker
reads rows (:func:`lm629_host.bench.scope.feed`: recorded on the far side where the link can,
host-polled elsewhere), and when a command is queued it closes the recording, runs the
command through the command line's own code (``run``: the same click command, validation and
one-line error as ``lm629 ...``) and starts recording again.

A command that waits on a move between bus programs of its own (an S-curve, whose pieces
the host times) gets a host-polled row read after its programs (``after_program``), so that
the plots go on during it; a step test's recording cannot share the link, and the test draws
its own response.

Time: an in-process simulator's clock runs only when something runs it, as fast as the model
computes; the worker paces it to the wall clock (rows, and the bus programs of a command that
waits, such as an S-curve move or a step test), so that the plots show a simulated axis in
real time.  On hardware the pace is the link's own.

A stop pressed while a command waits (a shaped move, a step test) is raised in the worker
after the bus program under way (the transport's ``after_program`` hook, as Ctrl-C is on the
command line): the command's own :func:`~lm629_host.chip.safety.stop_on_error` stops the
motor (abrupt stop, then motor off), and the stop asked for runs next, so that the axis ends
as the button's mode says (holding, or off).
"""

from __future__ import annotations

import collections
import math
import json
import logging
import queue
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from lm629_host.bench.scope import feed
from lm629_host.bus.opcodes import Signals, Status, wrap_counts
from lm629_host.bus.snapshot import Snapshot
from lm629_host.clock import WallClock
from lm629_host.physics.pid import sample_period_s
from lm629_host.errors import FailsafeTripped
from lm629_host.physics.units import FIXED_ONE

log = logging.getLogger("lm629_host.panel")


def error_line(exc: Exception) -> tuple[str, int]:
    """The command line's one line and exit code for ``exc``
    (:func:`lm629_host.cli.app.error_line`), imported when first needed: the command line's
    package imports this module (``lm629 panel``), so importing it here at the top made
    ``import lm629_host.panel.bench`` before the command line a circular import."""
    from lm629_host.cli.app import error_line as line
    return line(exc)

#: rows a second sampled for the plots, and messages a second sent to each page
SAMPLE_HZ = 50.0
PUBLISH_HZ = 25.0
#: seconds between reads of the link's failsafe (a trip the feeder sees shows at once)
FAILSAFE_POLL_S = 1.0


#: row periods beyond which two rows are too far apart for the velocity between them to be
#: plotted as the axis's velocity at the second (a host paused, a long command between them)
MAX_VELOCITY_SPAN_ROWS = 4


class Rows:
    """Snapshots -> the page's rows: ``[t, (desired, actual, desired velocity, actual
    velocity, status, signals) per axis]``, positions in counts, velocities in counts/s.

    Why the actual velocity is not RDRV: RDRV is the whole counts the encoder moved in the
    last sample alone (spec: "integer counts/sample"), a one-count step of which is a whole
    sample's worth of speed (3906 counts/s on an 8 MHz chip), and a row reads it once every
    ~78 samples.  An axis cruising at 1 count/sample reads 0 or 2 in the odd sample (the loop's
    drive steps between two output codes, the shaft's speed ripples a few per cent about the
    set speed), so a row that lands there plotted a stop or a doubled speed that never
    happened.  The actual velocity here is the real position's change since the previous row
    over the time between them: the mean over the row's interval, quantised to one count per
    interval (50 counts/s at 50 rows/s), never a reading the shaft did not make.  Where there
    is no previous row to measure from (the first, one after a command ran between them, which
    may redefine positions, one more than :data:`MAX_VELOCITY_SPAN_ROWS` periods after it) the
    actual velocity is None: a gap the page's line spans, never a value made up.  The desired
    velocity is RDDV, exact (16.16) at the row's sample."""

    def __init__(self, sample_s: float, rate_hz: float) -> None:
        self.sample_s = sample_s
        self.max_span_s = MAX_VELOCITY_SPAN_ROWS / rate_hz
        self._last: list[Snapshot] | None = None

    def restart(self) -> None:
        """The next row has no previous one to measure a velocity from (a command ran)."""
        self._last = None

    def row(self, snaps: list[Snapshot]) -> list[Any]:
        last = self._last
        self._last = snaps
        dt = snaps[0].time - last[0].time if last is not None else 0.0
        measured = last is not None and len(last) == len(snaps) and 0 < dt <= self.max_span_s
        out: list[Any] = [round(snaps[0].time, 5)]
        for k, s in enumerate(snaps):
            actual = (round(wrap_counts(s.real_position - last[k].real_position) / dt, 1)
                      if measured and last is not None else None)
            out += [s.desired_position, s.real_position,
                    round(s.desired_velocity / FIXED_ONE / self.sample_s, 1),
                    actual, int(s.status), int(s.signals)]
        return out


class PanelStop(KeyboardInterrupt):
    """The stop button, raised in the worker after the bus program under way, so that the
    waiting command's ``stop_on_error`` stops the motor as Ctrl-C does on the command line."""


@dataclass
class Outcome:
    """A command's end: exit code as the command line's, and what it printed or its one
    error line (``lm629: `` left off)."""

    code: int
    text: str
    data: Any = None

    @property
    def ok(self) -> bool:
        return self.code == 0

    def as_dict(self) -> dict[str, Any]:
        return {"ok": self.ok, "code": self.code, "text": self.text, "data": self.data}


@dataclass
class Job:
    argv: list[str]
    cs: int
    stop: bool = False
    then: Callable[[Outcome], Outcome] | None = None  #: turns the outcome into the answer
    #: a command that waits on a move between programs of its own (an S-curve): rows are
    #: read between them (host-polled), so that the plots go on during it
    live: bool = False
    done: threading.Event = field(default_factory=threading.Event)
    outcome: Outcome | None = None


Runner = Callable[[list[str]], Outcome]


class BenchWorker:
    """Owns ``session``'s board; :meth:`submit` a command, :meth:`subscribe` to the rows."""

    def __init__(self, session: Any, run: Runner, axes: list[tuple[int, str]],
                 sample_hz: float = SAMPLE_HZ) -> None:
        self.session = session
        self._run = run
        self.axes = axes
        self.sample_hz = sample_hz
        self._jobs: collections.deque[Job] = collections.deque()
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._quit = False
        self._busy: Job | None = None
        self._stop_asked = False
        self._subscribers: set[queue.Queue[str]] = set()
        self._rows: list[list[Any]] = []
        self._published = 0.0
        self._sampled = 0.0  #: when the last row was taken (monotonic)
        self._in_hook = False
        self._wall0 = self._clock0 = 0.0
        self.failsafe: dict[str, Any] = {"armed": None, "text": "none on this link"}
        self.source = ""
        self.sample_s = sample_period_s(session.clock_hz)
        self.rows = Rows(self.sample_s, sample_hz)
        self.error: str | None = None  #: what ended the worker, as the command line's line
        self.exception: Exception | None = None
        #: the gains loaded on each axis as far as the host knows (no register reads them
        #: back): the profile's, a simulator's kp = 20, then each applied from the page
        self.gains: dict[int, dict[str, int]] = {}
        self._thread = threading.Thread(target=self._main, name="lm629-panel-bench", daemon=True)
        self.ready = threading.Event()

    # ------------------------------------------------------------------ from other threads
    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        """End the worker; an axis still moving is stopped first (the panel's process is
        ending: every way it ends stops a moving motor, as any command's)."""
        with self._lock:
            self._quit = True
            if self._busy is not None and not self._busy.stop:
                self._stop_asked = True  # a command under way (an S-curve) ends as by Ctrl-C
        self._wake.set()
        self._thread.join(timeout=30)

    def subscribe(self) -> queue.Queue[str]:
        q: queue.Queue[str] = queue.Queue(maxsize=500)
        with self._lock:
            self._subscribers.add(q)
        return q

    def unsubscribe(self, q: queue.Queue[str]) -> None:
        with self._lock:
            self._subscribers.discard(q)

    def submit(self, argv: list[str], cs: int, *, stop: bool = False,
               then: Callable[[Outcome], Outcome] | None = None, live: bool = False,
               timeout: float = 600.0) -> Outcome:
        """Run ``argv`` on axis ``cs`` in the worker and wait for its outcome.  A stop goes
        first: it cancels the commands queued behind it and interrupts one that waits."""
        job = Job(argv, cs, stop, then, live)
        with self._lock:
            if self._quit or not self._thread.is_alive():
                return Outcome(3, "the panel is ending" if self._quit else
                               f"the bench stopped: {self.error}")
            if stop:
                for old in self._jobs:
                    old.outcome = Outcome(2, "cancelled: the stop button was pressed first")
                    old.done.set()
                self._jobs.clear()
                if self._busy is not None and not self._busy.stop:
                    self._stop_asked = True
            self._jobs.append(job)
        self._wake.set()
        if not job.done.wait(timeout):
            return Outcome(8, f"no answer from the bench within {timeout:g} s")
        assert job.outcome is not None
        return job.outcome

    def publish(self, message: dict[str, Any]) -> None:
        text = json.dumps(message, separators=(",", ":"))
        with self._lock:
            subs = list(self._subscribers)
        for q in subs:
            try:
                q.put_nowait(text)
            except queue.Full:  # a page that stopped reading: drop its oldest message
                try:
                    q.get_nowait()
                    q.put_nowait(text)
                except (queue.Empty, queue.Full):
                    pass

    # ------------------------------------------------------------------ the worker thread
    def _main(self) -> None:
        try:
            board = self.session.board()
            transport = board.transport
            self._transport = transport
            self._board = board
            self._real_time = isinstance(getattr(transport, "clock", None), WallClock)
            previous = transport.after_program
            transport.after_program = self._after_program(previous)
            far = len(self.axes) == 1 and transport.records_on_far_side
            self.source = ("far-side recording: " + transport.record_note() if far else
                           "host polls: one round trip a row, timed by the host")
        except Exception as exc:  # noqa: BLE001 - said on the page and by the command
            self._fault(exc)
            self.ready.set()
            return
        self.ready.set()
        cs = [c for c, _n in self.axes]
        self._rebase()
        self._poll_failsafe()
        # a link without a failsafe (sim://, the FT232H) is never asked again: each read ends
        # a far-side recording, which then starts over
        last_failsafe = time.monotonic() if self.failsafe["armed"] is not None else math.inf
        try:
            while not self._quit:
                try:
                    self._sample(board, cs, last_failsafe)
                except FailsafeTripped as exc:  # a host paused past the failsafe: the bridge
                    # stopped the chips; said on the page, and the rows go on
                    self._failsafe_news({"armed": True, "tripped": True,
                                         "text": error_line(exc)[0]})
                if time.monotonic() - last_failsafe >= FAILSAFE_POLL_S:
                    last_failsafe = time.monotonic()
                    self._poll_failsafe()
                self._run_jobs()
        except Exception as exc:  # noqa: BLE001 - the link failed: said on the page
            self._fault(exc)
            self.publish({"type": "fault", "text": f"the bench stopped: {self.error}"})
        finally:
            self._end(board)

    def _sample(self, board: Any, cs: list[int], last_failsafe: float) -> None:
        """Rows until a job is queued, the panel ends or the failsafe is due a read."""
        rows: Iterator[list[Snapshot]] = feed(board, cs, self.sample_hz)
        try:
            for snaps in rows:
                self._add(snaps)
                self._pace(snaps[0].time)
                if self._jobs or self._quit or \
                        time.monotonic() - last_failsafe >= FAILSAFE_POLL_S:
                    break
        finally:
            close = getattr(rows, "close", None)
            if close is not None:
                close()  # ends the far side's recording

    def _fault(self, exc: Exception) -> None:
        self.exception = exc
        self.error = error_line(exc)[0]

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def _end(self, board: Any) -> None:
        from lm629_host.chip.safety import stop_if_moving
        with self._lock:
            for job in self._jobs:
                job.outcome = Outcome(3, "the panel is ending")
                job.done.set()
            self._jobs.clear()
        for cs, _name in self.axes:
            try:
                if stop_if_moving(board.axis(cs)):
                    log.warning("axis %s was moving: stopped (abrupt stop) as the panel ended", cs)
            except Exception:  # noqa: BLE001 - the link may be what failed
                pass

    def _run_jobs(self) -> None:
        while True:
            with self._lock:
                if not self._jobs or self._quit:
                    self._wake.clear()
                    return
                job = self._jobs.popleft()
                self._busy = job
            try:
                self.session.select_axis(job.cs)
                self._rebase()
                self.rows.restart()
                outcome = self._run(job.argv)
                if job.then is not None and outcome.ok:
                    outcome = job.then(outcome)
            except Exception as exc:  # noqa: BLE001 - a command's fault is its answer
                message, code = error_line(exc)
                outcome = Outcome(code, message)
            with self._lock:
                self._busy = None
                self._stop_asked = False
            job.outcome = outcome
            job.done.set()
            if self.failsafe["armed"] is not None:  # a trip a command met, a clear
                self._poll_failsafe()
            self.publish({"type": "log", "argv": job.argv, "axis": self._name(job.cs),
                          **outcome.as_dict(), "data": None})
            self._rebase()

    def _after_program(self, previous: Callable[[], None] | None) -> Callable[[], None]:
        def hook() -> None:
            if previous is not None:
                previous()
            if self._busy is None or self._busy.stop:
                return
            if self._stop_asked:
                self._stop_asked = False
                raise PanelStop("the panel is ending" if self._quit else "stopped from the panel")
            if not self._real_time:
                self._pace(self._transport.clock.now(), wake=False)
            if self._busy.live and not self._in_hook and \
                    time.monotonic() - self._sampled >= 1.0 / self.sample_hz:
                self._in_hook = True  # the snapshot's own program ends here too
                try:
                    self._add(self._board.snapshots([c for c, _n in self.axes]))
                finally:
                    self._in_hook = False
        return hook

    def _rebase(self) -> None:
        self._wall0 = time.monotonic()
        self._clock0 = self._transport.clock.now()

    def _pace(self, t: float, wake: bool = True) -> None:
        """Hold the worker until the wall clock has caught up with the transport's time ``t``
        (a simulated clock runs ahead as fast as the model computes); a queued job ends the
        wait at once (``wake``)."""
        ahead = (t - self._clock0) - (time.monotonic() - self._wall0)
        if ahead < -0.5:  # behind (a paused host, a slow model): start again from here
            self._rebase()
        elif ahead > 0:
            if wake:
                self._wake.wait(min(ahead, 1.0))
            else:
                time.sleep(min(ahead, 1.0))

    def _add(self, snaps: list[Snapshot]) -> None:
        self._sampled = time.monotonic()
        self._rows.append(self.rows.row(snaps))
        now = time.monotonic()
        # every other row at 50 rows/s: half a row's slack, so that a row a little early does
        # not wait for the next one (which would make it 1 in 3)
        if now - self._published >= 1.0 / PUBLISH_HZ - 0.5 / self.sample_hz:
            self._published = now
            rows, self._rows = self._rows, []
            self.publish({"type": "rows", "rows": rows})
        report = getattr(self._transport, "failsafe_report", None)
        if report is not None and report.tripped and not self.failsafe.get("tripped"):
            self._failsafe(report)

    def _poll_failsafe(self) -> None:
        try:
            state = self._transport.failsafe_state()
        except Exception as exc:  # noqa: BLE001 - said on the page; the rows go on
            self.failsafe = {"armed": None, "text": f"could not read the failsafe: {exc}"}
            self.publish({"type": "failsafe", **self.failsafe})
            return
        if state is None:
            return
        self._failsafe(state)

    def _failsafe(self, state: Any) -> None:
        names = {cs: name for cs, name in self.axes}
        armed = state.timeout_ms > 0
        text = (state.describe(names) if state.tripped else
                f"armed: {state.timeout_ms} ms" if armed else "disarmed")
        self._failsafe_news({"armed": armed, "tripped": bool(state.tripped), "text": text})

    def _failsafe_news(self, new: dict[str, Any]) -> None:
        if new != self.failsafe:
            self.failsafe = new
            self.publish({"type": "failsafe", **new})

    def _name(self, cs: int) -> str:
        return next((n for c, n in self.axes if c == cs), str(cs))


#: the status and signal bits the page shows as lights, in order
STATUS_BITS = [(b.name or "", int(b)) for b in Status]
SIGNAL_BITS = [(b.name or "", int(b)) for b in Signals]

__all__ = ["BenchWorker", "MAX_VELOCITY_SPAN_ROWS", "Outcome", "PanelStop", "Rows", "SAMPLE_HZ",
           "SIGNAL_BITS", "STATUS_BITS"]
