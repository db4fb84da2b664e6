"""The transport interface: run a bus program on one chip, count the work, keep the clock.

A transport has one job, :meth:`Transport.execute`: the lock, the nesting depth, the chip-select
range check, the program count and the observers are done there, once; each transport runs the
program itself in ``_execute``.  Two shapes exist:

* a transport whose far side can poll busy itself (the serial bridge) sends the whole program
  and gets the results back in one round trip: it subclasses :class:`Transport` directly;
* a transport that drives the pins cycle by cycle (the simulator, a plain GPIO adapter)
  subclasses :class:`CycleTransport` and supplies five primitive bus cycles; the busy
  discipline, the timeout on the transport's clock, the trace and the counters are done here,
  once.

Every transport has a ``clock`` (``now()``, ``sleep(seconds)``): the wall clock for hardware,
the simulated clock for simulators, so that everything that waits (busy polls, the 1.5 ms reset
wait, ``LM629.wait_for``) waits on the right time base.
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Iterator, Sequence
import functools
import logging
import threading
from typing import TYPE_CHECKING, Any, final

from lm629_host.clock import Clock, WallClock
from lm629_host.transports.reports import (
    HOST_POLLED_NOTE,
    Check,
    PortInfo,
    ProfileState,
    RawRow,
    Stats,
)
from lm629_host.transports.keepalive import FeedingClock
from lm629_host.transports import exiting
from lm629_host.urls import Option, PortURL, port_url
from lm629_host.errors import AxisError, TransportError
from lm629_host.bus.program import (
    BusCycle,
    Program,
    ProgramResult,
    TraceCallback,
)

if TYPE_CHECKING:
    from lm629_host.bridge.protocol.failsafe import FailsafeState

log = logging.getLogger("lm629_host.bus")


#: the ``__init__`` and ``close`` wrappers :meth:`Transport.__init_subclass__` made (a subclass
#: that inherits one is not wrapped again)
_WRAPPERS: set[Callable[..., None]] = set()


class LockedClock(Clock):
    """A simulated clock whose ``sleep`` runs the simulation forward under the transport's
    lock, so that a thread waiting on it never advances the chip model in the middle of
    another thread's bus program.  Everything else is the wrapped clock's."""

    def __init__(self, clock: Clock, lock: threading.RLock) -> None:
        self._clock = clock
        self._lock = lock
        self.now = clock.now  # type: ignore[method-assign]  # no wrapper on the hot path

    @property
    def inner(self) -> Clock:
        """The clock this one wraps."""
        return self._clock

    def now(self) -> float:
        return self._clock.now()

    def sleep(self, seconds: float) -> None:
        with self._lock:
            self._clock.sleep(seconds)

    def __getattr__(self, name: str) -> object:
        return getattr(self._clock, name)


class BusObserver:
    """Sees what a transport runs: subscribe with :meth:`Transport.add_observer`.  Override
    what you need; the defaults do nothing.  The pytest plugin (its failure report and motion
    guard) and ``--trace`` are observers; nothing else hooks into :meth:`Transport.execute`."""

    def program_starting(self, transport: Transport, program: Program) -> None:
        """Before any bus cycle of ``program``, under the transport's lock; raising refuses
        the program (nothing is sent, the exception reaches the caller, and no observer is
        told the program ended: it never started)."""

    def program_ended(self, transport: Transport, program: Program,
                      result: ProgramResult | None, error: BaseException | None) -> None:
        """After ``program``, still under the lock: its ``result``, or the ``error`` it
        raised (``result`` None)."""

    def bus_cycle(self, cycle: BusCycle) -> None:
        """Every bus cycle, busy polls included.  Only an observer that overrides this gets
        them: while one is subscribed the simulators take their general loop, which makes
        every poll (slower), so a program-level observer costs nothing of the kind."""


class _CycleCallback(BusObserver):
    """The ``trace=`` callable of a transport, as an observer of bus cycles."""

    def __init__(self, callback: TraceCallback) -> None:
        self.callback = callback

    def bus_cycle(self, cycle: BusCycle) -> None:
        self.callback(cycle)


class Transport(abc.ABC):
    """Runs bus programs on one chip.  Subclasses set ``url``, ``clock`` and ``has_reset_line``.

    The contract of a transport class, all that the registry (:mod:`lm629_host.transports`),
    :func:`lm629_host.open`, ``lm629 list`` and ``lm629 doctor`` use:

    * ``scheme``: the URL scheme it is registered under;
    * ``simulated``: True when no hardware is behind it (the CLI prepares a fresh chip);
    * :meth:`from_url` opens one; :meth:`execute` runs a bus program (final: a subclass
      implements ``_execute``); :meth:`close`;
    * :meth:`list_ports` and :meth:`doctor` (class methods, empty by default) say what this
      machine has for this kind of port and what is wrong with it;
    * :meth:`describe` and ``repr()`` say what an open one is connected to.

    Threads: every ``execute`` runs whole under ``self.lock`` (one re-entrant lock per
    transport, so shared by every :class:`~lm629_host.LM629` on it): threads sharing a chip
    never interleave bus cycles.  A simulated clock (anything but :class:`WallClock`) is
    wrapped so that its ``sleep``, which runs the simulation, takes the same lock.

    Observers (:class:`BusObserver`, :meth:`add_observer`) see every program and, when they
    ask for them, every bus cycle; ``trace=`` is one that sees the cycles.
    """

    #: the scheme this transport is registered under (``sim``, ``serial``...)
    scheme: str = ""
    #: True when the far side is simulated: no hardware, a fresh chip at every open
    simulated: bool = False
    #: its URL options, one table (the board's rows first): what :meth:`from_url` parses the
    #: URL against, once, and what a message about an unknown name lists
    options: tuple[Option, ...] = ()
    #: bus programs under way (nested ones count): a signal handler that must not cut a
    #: program in half reads it (the CLI's)
    program_depth: int = 0
    #: called after every outermost bus program that ended normally, outside the lock (the CLI
    #: raises a stop signal there that it held during the program); None: nothing
    after_program: Callable[[], None] | None = None
    #: True when the transport can pulse /RST; otherwise ``LM629.reset`` sends command RESET
    has_reset_line: bool = True
    #: how many chips (/CS lines) a program can address with ``Op.SELECT`` (a multi-axis board)
    chip_selects: int = 1
    #: True when it runs ``Op.WAIT_STATUS`` (a wait for a status bit on the far side); without
    #: it, ``LM629.wait_for`` polls from the host
    has_wait_status: bool = False
    #: True when one program may carry a far-side wait between its commands (a WAIT_STATUS
    #: inside a longer program): then ``Move.wait`` finds a move's end in one exchange
    far_waits: bool = False
    #: the longest far-side wait one exchange may hold, seconds (None: no limit): a bridge
    #: whose failsafe is armed counts a wait as the host alive only up to its timeout
    far_wait_limit_s: float | None = None
    #: how much later than the far-side wait of a ``command; wait; status`` program its status
    #: read may land, us (the far side's own time between the two, and the wait's own
    #: rounding): a busy time measured that way (``lm629 selftest``) is short of the chip's
    #: by up to this.  A cycle-at-a-time transport: one bus cycle (0.5 us simulated)
    busy_probe_us: float = 1.0
    #: True when the far side issues a shaped move's pieces on its own timer
    #: (:meth:`profile`); otherwise the host times them on ``clock``
    far_profiles: bool = False
    #: the most pieces the far side holds at once
    profile_capacity: int = 0
    #: True when a schedule longer than ``profile_capacity`` is streamed to the far side in
    #: top-ups (:meth:`profile`), so it stays timed there; False: a longer one is host-timed
    profile_streams: bool = False

    #: the subscribed observers, and those of them that want bus cycles (tuples, replaced
    #: whole on a change, so that a program in another thread iterates a stable one)
    _observers: tuple[BusObserver, ...] = ()
    _cycle_observers: tuple[BusObserver, ...] = ()
    _trace_observer: _CycleCallback | None = None

    #: True once :meth:`close` ran: every program (and recording) after it is a
    #: :class:`TransportError` that says the port is closed, before anything is sent
    _closed: bool = False

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """A transport's own ``close`` marks it closed once it has run, so that the rule
        "a call on a closed port raises, saying closed" (:meth:`check_open`) holds for every
        transport, an entry point's too, without each one keeping it."""
        super().__init_subclass__(**kwargs)
        init = cls.__dict__.get("__init__")
        if init is not None and init not in _WRAPPERS:
            # a transport whose making failed was never handed to anyone: the exit does not
            # close it (half made, it may lack what its close needs)
            @functools.wraps(init)
            def made(self: Transport, *args: Any, **kw: Any) -> None:
                try:
                    init(self, *args, **kw)
                except BaseException:
                    exiting.forget(self)
                    raise
            _WRAPPERS.add(made)
            cls.__init__ = made  # type: ignore[method-assign]  # the subclass's own, wrapped
        own = cls.__dict__.get("close")
        if own is None or own in _WRAPPERS:
            return

        @functools.wraps(own)
        def close(self: Transport) -> None:
            try:
                own(self)
            finally:
                self._closed = True
                exiting.forget(self)
        _WRAPPERS.add(close)  # wrapped once per class
        cls.close = close  # type: ignore[method-assign]  # the subclass's own, wrapped

    def check_open(self) -> None:
        """Raise :class:`TransportError` saying the port is closed when :meth:`close` has run
        (:meth:`execute` asks first; a recording asks before it plans its rate)."""
        if self._closed:
            raise TransportError("the port is closed (close() was called): open it again "
                                 "(lm629_host.open) to talk to the chip", port=self.url)

    def __init__(self, url: str | PortURL, *, trace: TraceCallback | None = None) -> None:
        #: the port as the user wrote it (messages quote it); the options the CLI or a profile
        #: added beside it are in :attr:`port_url`
        self.url = str(url)
        self.port_url = port_url(url)
        self.trace = trace
        self.stats = Stats()
        self.clock = WallClock()
        exiting.track(self)  # a normal exit closes it if the script does not (.exiting)

    @final
    def execute(self, program: Program) -> ProgramResult:
        """Run ``program`` whole under :attr:`lock`; return its results or raise an
        :class:`~lm629_host.LM629Error` subclass that names the failing operation.  A chip
        select the transport does not have is an :class:`AxisError` before any bus cycle.
        Final: a transport runs the program in ``_execute``, so that the lock, the count and
        the observers cannot be left out."""
        with self.lock:
            self.check_open()
            self.program_depth += 1
            observers = self._observers  # the ones subscribed when the program starts
            try:
                for obs in observers:
                    obs.program_starting(self, program)
                try:
                    if program.top_select >= self.chip_selects:
                        raise AxisError(program.top_select, self.chip_selects, self.describe())
                    self.stats.programs += 1
                    result = self._execute(program)
                except BaseException as exc:
                    for obs in observers:
                        obs.program_ended(self, program, None, exc)
                    raise
                for obs in observers:
                    obs.program_ended(self, program, result, None)
            finally:
                self.program_depth -= 1
        hook = self.after_program
        if hook is not None and not self.program_depth:
            hook()
        return result

    def add_observer(self, observer: BusObserver) -> None:
        """Show ``observer`` every bus program from now on (and every bus cycle when it
        overrides :meth:`BusObserver.bus_cycle`), in the order observers were added."""
        with self.lock:
            self._observers = (*self._observers, observer)
            if type(observer).bus_cycle is not BusObserver.bus_cycle:
                self._cycle_observers = (*self._cycle_observers, observer)

    def remove_observer(self, observer: BusObserver) -> None:
        """Stop showing ``observer`` anything (nothing happens when it was not subscribed)."""
        with self.lock:
            self._observers = tuple(o for o in self._observers if o is not observer)
            self._cycle_observers = tuple(o for o in self._cycle_observers if o is not observer)

    @property
    def trace(self) -> TraceCallback | None:
        """A callable given every bus cycle (``trace=`` at open), or None; setting it replaces
        the previous one (an observer of cycles, see :meth:`add_observer`)."""
        return self._trace_observer.callback if self._trace_observer is not None else None

    @trace.setter
    def trace(self, callback: TraceCallback | None) -> None:
        if self._trace_observer is not None:
            self.remove_observer(self._trace_observer)
        self._trace_observer = None if callback is None else _CycleCallback(callback)
        if self._trace_observer is not None:
            self.add_observer(self._trace_observer)

    @property
    def clock_hz(self) -> float | None:
        """The chip's clock input in Hz when this transport knows it: a simulator gives its
        model's; hardware cannot read it from the chip (None: the caller assumes one, see
        :attr:`LM629.clock_hz <lm629_host.LM629.clock_hz>`)."""
        return None

    @property
    def chip_count(self) -> int | None:
        """How many chips are known to be on the bus: a simulator's are the ones it built
        (fewer than its adapter's ``chip_selects``); None on hardware, where only
        ``chip_selects`` is known."""
        return None

    @property
    def lock(self) -> threading.RLock:
        """The lock every bus program of this transport runs under (see the class doc)."""
        lock = self.__dict__.get("_lock")
        if lock is None:
            lock = self.__dict__.setdefault("_lock", threading.RLock())
        return lock

    @property
    def clock(self) -> Clock:
        """``now()`` and ``sleep()``: the wall clock on hardware, simulated on simulators."""
        return self._clock

    @clock.setter
    def clock(self, clock: Clock) -> None:
        inner = clock
        while isinstance(inner, (LockedClock, FeedingClock)):  # the time base under wrappers
            inner = inner.inner
        if not isinstance(clock, (WallClock, LockedClock)):
            clock = LockedClock(clock, self.lock)
        self._clock = clock
        #: the clock itself, for code that already holds the lock (inside ``execute``)
        self._inner_clock = inner

    @property
    def time_base(self) -> Clock:
        """The clock under any wrapper (the lock's, a keep-alive's): the time itself."""
        return self._inner_clock

    @property
    def on_wall_clock(self) -> bool:
        """True when the transport's time base is the wall clock (hardware), False on a
        simulated one (under any wrapper)."""
        return isinstance(self._inner_clock, WallClock)

    @property
    def closed(self) -> bool:
        """True once :meth:`close` ran."""
        return self._closed

    @classmethod
    def from_url(cls, url: str | PortURL, *, trace: TraceCallback | None = None) -> Transport:
        """Open the port named by ``url`` (its options after ``?``: see the subclass)."""
        raise TransportError(f"{cls.__name__} cannot be opened from a URL", port=str(url))

    @classmethod
    def list_ports(cls) -> list[PortInfo]:
        """The ports of this kind found on this machine (``lm629 list``)."""
        return []

    @classmethod
    def doctor(cls, port: str | None = None) -> list[Check]:
        """What ``lm629 doctor`` says about this kind of port on this machine (libraries,
        permissions, adapters found); ``port``: one port to examine closely."""
        return []

    @abc.abstractmethod
    def _execute(self, program: Program) -> ProgramResult:
        """Run ``program`` (called by :meth:`execute`, which holds the lock, counted the
        program and checked its chip selects); return its results or raise an
        :class:`~lm629_host.LM629Error` subclass that names the failing operation."""

    def feed(self) -> None:  # noqa: B027 - optional: most far sides keep no watchdog
        """Tell the far side's watchdog the host is alive (a bridge's failsafe with
        ``failsafe_feed=script``); nothing where there is none."""

    def close(self) -> None:
        """Release the port.  Idempotent; every call after it raises (:meth:`check_open`)."""
        self._closed = True
        exiting.forget(self)

    # ------------------------------------------------------------------ the link failsafe
    # A bridge keeps a timer on its side of the link and stops every chip when the host falls
    # silent (transports/link.py).  Transports without one report None.

    def failsafe_state(self) -> FailsafeState | None:
        """The far side's failsafe (armed timeout, action, a latched trip), or None when the
        far side keeps none (the FT232H, ``sim://``)."""
        return None

    def clear_failsafe(self) -> FailsafeState | None:
        """Acknowledge a latched failsafe trip; returns it (None: none, or no failsafe)."""
        return None

    # ------------------------------------------------------------------ recording
    # The contract of LM629.record (lm629_host.chip.recording): a transport delivers rows of a
    # sample program (status reads, data-reporting commands, READs) run every period.  The
    # default below polls from the host on the transport's clock: exact where that clock is
    # the chip's own (the simulators), host-timed on hardware (HOST_POLLED_NOTE).  A transport
    # whose far side samples on its own timer (the bridge's RECORD) overrides all three.

    @property
    def records_on_far_side(self) -> bool:
        """True when the rows of :meth:`record_rows` are timed where the chip is: a far side's
        own timer, or the strobes of a simulator that drives the chip's pins itself
        (:class:`CycleTransport` on a simulated clock).  False: host-polled, one exchange a
        row (:meth:`record_note` says what that means): the FT232H, a bridge without RECORD."""
        return False

    def record_note(self) -> str:
        """One sentence: how this transport records (for the CLI and error messages)."""
        if self.records_on_far_side:
            return "rows sampled on the chip's own clock (simulated): exact"
        if isinstance(self.clock, WallClock):
            return HOST_POLLED_NOTE
        return HOST_POLLED_NOTE.replace("host's clock", "host's (simulated) clock")

    def record_max_rate(self, program: Program) -> float | None:
        """The highest rate (rows/s) at which ``program`` can be recorded, or None when the
        transport cannot tell before it tries (the host-polled default on hardware)."""
        return None

    def profile(self, axis: int | None, pieces: Sequence[tuple[float, int]], *,
                new: bool) -> ProfileState:
        """Hand a shaped move's pieces to the far side (``far_profiles``): each (seconds from
        now, velocity word) is an LTRJ of that maximum velocity and an STT on chip ``axis``
        (None: the transport's own), issued on the far side's timer; ``new`` drops what an
        older schedule still holds.  No pieces and ``new=False``: what the schedule did."""
        raise NotImplementedError(f"{type(self).__name__} issues no pieces on its far side")

    def record_rows(self, program: Program, period_s: float, rows: int) -> Iterator[RawRow]:
        """Run ``program`` every ``period_s`` for ``rows`` rows (0: until the iterator is
        closed), yielding each row as it comes.  The default polls from the host: each row is
        one :meth:`execute` at its due time on :attr:`clock`; a due time already a period
        past when the host gets to it is skipped, a gap (never a row made up)."""
        clock = self.clock
        t0 = clock.now()
        k = 0
        while not rows or k < rows:
            due = t0 + k * period_s
            now = clock.now()
            if now < due:
                clock.sleep(due - now)
            elif now >= due + period_s:  # the host fell behind: those rows are gaps
                k = int((now - t0) / period_s)
                if rows and k >= rows:
                    return
            t = clock.now()
            r = self.execute(program)
            yield RawRow(k, t, r.words, r.statuses)
            k += 1

    def describe(self) -> str:
        """One line for the CLI and error messages: what this transport is connected to."""
        return self.url

    def port_checks(self) -> list[Check]:
        """What ``lm629 doctor`` shows about this open port once programs have run on it (how
        the transport fitted itself to the chip); none by default."""
        return []

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.url!r}>"

    def _tracing(self) -> bool:
        """True when someone looks at single bus cycles (an observer of cycles, debug log)."""
        return bool(self._cycle_observers) or log.isEnabledFor(logging.DEBUG)

    def _emit(self, cycle: BusCycle) -> None:
        for obs in self._cycle_observers:
            obs.bus_cycle(cycle)
        if log.isEnabledFor(logging.DEBUG):
            log.debug("%s %s", self.scheme or "bus", cycle)

    def __enter__(self) -> Transport:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
