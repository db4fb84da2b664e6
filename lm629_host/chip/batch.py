"""Several typed calls as one bus program: :meth:`LM629.batch <lm629_host.LM629.batch>` and,
over several axes of one bus, :meth:`Board.batch <lm629_host.Board.batch>`.

Why: on a bridge every program is an exchange, and behind USB an exchange costs what the
adapter makes it cost (4.096 ms on an Uno), so ten calls cost ten exchanges.  A batch queues
the calls and sends their programs as one when the ``with`` block ends: one exchange.

How, without a second copy of each command's encoding: everything goes through the chip's
public interception points, :meth:`LM629.shadow <lm629_host.LM629.shadow>` (a copy with its own
host-side state, whose programs all go to a runner) and :meth:`LM629.intercept
<lm629_host.LM629.intercept>` (this thread's programs of the chip itself to a runner).  A call
queued is made at once on a shadow of the chip, its bus answered as a chip that raised no flag
would (words 0, status 00): bad arguments raise there, nothing is sent and the chip object is
untouched.  When the block ends, under the transport's
lock: every call is made again on fresh shadows, in order, from the chip's state at that moment
(what direct calls inside the block left), to build the programs; they run as one; then every
call is made on the chip itself, its bus answered with its own share of the real results, so
that each method decodes its words, checks its statuses and keeps its host-side state exactly
as it does outside a batch (``start`` raises :class:`CommandError` when its STT is refused),
and that return value is the handle's ``.value``.  An error names the call ("batch call 3 of
10, start()").  A call whose program would differ on that pass (the state it depends on came
out otherwise) is an error too: it never runs a program other than the one sent.

Threads: the interception is per thread, so a batch captures only the calls its own thread
queues; other threads' calls on the same chip reach the bus as usual (waiting for the lock while
the batch's program runs).  A batch object belongs to the thread that made it: queuing on it,
entering it or running it from another thread is a RuntimeError at once, before anything is
queued (its queue and its shadows are not shared safely, and a call queued while another thread
runs the batch would be lost).  Each thread opens its own batch.

Nesting: a batch opened inside another one's block on the same bus and thread is refused
(RuntimeError): its programs would reach the bus before the outer batch's, which were queued
first.  Queue the calls on the outer batch instead.

Only calls that are one bus program can be queued (:data:`BATCHABLE`); ``reset``, waits and
moves that read before they start are not.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from contextlib import AbstractContextManager, ExitStack
from dataclasses import dataclass, field
from typing import Any, Generic, Protocol, TypeVar

from lm629_host.errors import LM629Error
from lm629_host.bus.program import STATUS_OPS, Op, Program, ProgramResult
from lm629_host.transports.base import Transport

T = TypeVar("T")


class BatchChip(Protocol):
    """What a batch needs of a chip (an :class:`~lm629_host.LM629`; declared here so that
    this module does not import the typed layer back)."""

    transport: Transport
    chip_select: int
    busy_timeout: float

    def intercept(self, runner: Callable[[Program], ProgramResult]) -> AbstractContextManager[None]: ...

    def shadow(self, runner: Callable[[Program], ProgramResult]) -> BatchChip: ...


#: the typed calls a batch takes: each is exactly one bus program
BATCHABLE = frozenset({
    "read_status", "sync", "is_moving", "read_signals", "snapshot", "mask_interrupts",
    "reset_interrupts", "define_home", "set_index_position", "load_position_error",
    "set_breakpoint", "load_filter", "update_filter", "load_trajectory", "start", "port8",
    "port12", "read_desired_position", "read_real_position", "read_index_position",
    "read_desired_velocity", "read_real_velocity", "read_integration_sum", "raw"})


class Handle(Generic[T]):
    """What a queued call returns: its ``value`` once the batch has run."""

    def __init__(self, label: str) -> None:
        self.label = label
        self._done = False
        self._value: Any = None

    def resolve(self, value: Any) -> None:
        """The batch ran this call: ``value`` is its result."""
        self._value, self._done = value, True

    @property
    def value(self) -> T:
        if not self._done:
            raise RuntimeError(f"{self.label}: the batch has not run yet (it runs when its "
                               "`with` block ends)")
        return self._value

    def __repr__(self) -> str:
        return f"<Handle {self.label}: {self._value!r}>" if self._done else \
            f"<Handle {self.label}: pending>"


@dataclass
class _Call:
    label: str
    chip: BatchChip
    name: str
    args: tuple[Any, ...]
    kwargs: dict[str, Any]
    handle: Handle[Any]
    program: Program = field(default_factory=Program)  #: built when the batch runs
    first: int = 0  #: index of its first operation in the batch's program


def _dummy(program: Program) -> ProgramResult:
    """The answer of a chip that raised no flag: words 0, status bytes 00."""
    words = tuple(0 for o in program.ops if o.op is Op.READ)
    statuses = tuple(0 for o in program.ops if o.op in STATUS_OPS)
    return ProgramResult(words, statuses, 0, False)


def _name_call(exc: LM629Error, where: str) -> None:
    """Put the call into the error's message (and ``exc.batch_call``)."""
    exc.batch_call = where  # type: ignore[attr-defined]  # an extra attribute for callers
    if exc.args:
        exc.args = (f"{where}: {exc.args[0]}",) + exc.args[1:]


class _Collector:
    """The runner of a batch's shadows: keeps each program and answers it as a chip that
    raised no flag would."""

    def __init__(self) -> None:
        self.programs: list[Program] = []

    def __call__(self, program: Program) -> ProgramResult:
        self.programs.append(program)
        return _dummy(program)

    def program_of(self, shadow: BatchChip, call: _Call) -> Program:
        """The one program ``call`` makes on ``shadow`` (whose runner this is)."""
        programs = self.programs
        programs.clear()
        try:
            getattr(shadow, call.name)(*call.args, **call.kwargs)
        except LM629Error:
            pass  # an error from the dummy answer: the real one will tell
        if len(programs) != 1:
            raise TypeError(f"{call.label} ran {len(programs)} bus programs: a batch takes "
                            "one each")
        return programs[0]


class _Answers:
    """The runner of the chips while a batch decodes: each call's share of the results, and
    the programs the call made (to check that they are the one sent)."""

    def __init__(self) -> None:
        self.share = ProgramResult()
        self.seen: list[Program] = []

    def __call__(self, program: Program) -> ProgramResult:
        self.seen.append(program)
        return self.share


class _Queue:
    """The calls of one chip, queued into a batch: ``b.read_status()``, ``b[axis].snapshot()``."""

    def __init__(self, batch: Batch, chip: BatchChip) -> None:
        self._batch = batch
        self._chip = chip

    def __getattr__(self, name: str) -> Callable[..., Handle[Any]]:
        if name.startswith("_") or name not in BATCHABLE:
            raise AttributeError(f"{name} cannot be queued in a batch (one bus program each "
                                 f"only: {', '.join(sorted(BATCHABLE))})")
        batch, chip = self._batch, self._chip

        def queue(*args: Any, **kwargs: Any) -> Handle[Any]:
            return batch.queue_call(chip, name, args, kwargs)
        return queue


class _OpenBatches(threading.local):
    """Per thread: the transports with a batch open in a ``with`` block."""

    def __init__(self) -> None:
        self.transports: list[Transport] = []


class Batch:
    """Typed calls queued on one chip, or on the axes of one bus (``b[axis].read_status()``),
    run as one bus program (see the module doc); use it as a context manager."""

    #: nesting is refused per thread and bus
    _open = _OpenBatches()

    def __init__(self, transport: Transport, chip: BatchChip | None = None,
                 axis_of: Callable[[Any], BatchChip] | None = None) -> None:
        self.transport = transport
        self.calls: list[_Call] = []
        self._chip = chip
        self._axis_of = axis_of
        #: per chip: the shadow its queued calls are checked on (their effects accumulate)
        self._shadows: dict[int, BatchChip] = {}
        self._collector = _Collector()
        self._ran = False
        self._entered = False
        #: the thread that made it: the only one that may queue, enter or run it
        self._owner = threading.current_thread()

    def _check_thread(self, what: str) -> None:
        here = threading.current_thread()
        if here is not self._owner:
            raise RuntimeError(
                f"{what}: this batch belongs to thread {self._owner.name!r} and was used from "
                f"{here.name!r}: a batch takes the calls of the thread that made it (nothing "
                "was queued); open a batch in this thread (chip.batch() or board.batch())")

    def __getattr__(self, name: str) -> Callable[..., Handle[Any]]:
        if name.startswith("_"):
            raise AttributeError(name)
        if self._chip is None:
            raise AttributeError(f"{name}: a board's batch queues each call on an axis: "
                                 f"b[axis].{name}(...)")
        return getattr(_Queue(self, self._chip), name)

    def __getitem__(self, axis: Any) -> _Queue:
        """The calls of one axis of the board (``b["x"]``, ``b[1]``: as ``board[...]``)."""
        if self._axis_of is None:
            raise TypeError("a chip's batch has no axes: queue on it directly (b.read_status()); "
                            "board.batch() takes b[axis]")
        chip = self._axis_of(axis)
        if chip.transport is not self.transport:
            raise ValueError(f"{axis!r} is not on this batch's bus ({self.transport.describe()})")
        return _Queue(self, chip)

    def queue_call(self, chip: BatchChip, name: str, args: tuple[Any, ...],
                   kwargs: dict[str, Any]) -> Handle[Any]:
        """Queue ``chip.name(*args, **kwargs)`` in this batch; its handle."""
        self._check_thread(f"{name}()")
        if self._ran:
            raise RuntimeError("this batch has run already: start a new one")
        shown = [repr(a) for a in args] + [f"{k}={v!r}" for k, v in kwargs.items()]
        where = f"axis {chip.chip_select}: " if self._chip is None else ""
        label = f"{where}{name}({', '.join(shown)})"
        call = _Call(label, chip, name, args, kwargs, Handle(label))
        shadow = self._shadows.get(id(chip))
        if shadow is None:
            shadow = self._shadows[id(chip)] = chip.shadow(self._collector)
        # ValueError for bad arguments: raised here, nothing queued
        self._collector.program_of(shadow, call)
        self.calls.append(call)
        return call.handle

    def run(self) -> None:
        """Run the queued calls as one program, then set every handle (raising the first
        call's error, which names the call)."""
        self._check_thread("run()")
        if self._ran:
            return
        self._ran = True
        if not self.calls:
            return
        with self.transport.lock:  # no other thread's program between building and decoding
            self._run_locked()

    def _run_locked(self) -> None:
        calls, n = self.calls, len(self.calls)
        shadows: dict[int, BatchChip] = {}
        collector = _Collector()
        whole = Program(busy_timeout_s=max(c.chip.busy_timeout for c in calls))
        at = 0  # a program starts on chip select 0
        for call in calls:
            shadow = shadows.get(id(call.chip))
            if shadow is None:
                shadow = shadows[id(call.chip)] = call.chip.shadow(collector)
            call.program = collector.program_of(shadow, call)
            call.first = len(whole.ops)
            ops = call.program.ops
            if call.chip.chip_select != at and not (ops and ops[0].op is Op.SELECT):
                whole.select(call.chip.chip_select)  # chip select 0 carries no SELECT of its own
            at = call.chip.chip_select
            whole.extend(call.program)
        try:
            result = self.transport.execute(whole)
        except LM629Error as exc:
            index = getattr(exc, "index", None)
            which = next((i for i, c in reversed(list(enumerate(calls)))
                          if isinstance(index, int) and c.first <= index), None)
            if which is not None:
                _name_call(exc, f"batch call {which + 1} of {n}, {calls[which].label}")
            raise
        words, statuses = iter(result.words), iter(result.statuses)
        answers = _Answers()
        with ExitStack() as intercepted:
            for chip in {id(c.chip): c.chip for c in calls}.values():
                intercepted.enter_context(chip.intercept(answers))
            for i, call in enumerate(calls):
                ops = call.program.ops
                w = tuple(next(words) for o in ops if o.op is Op.READ)
                st = tuple(next(statuses) for o in ops if o.op in STATUS_OPS)
                answers.share = ProgramResult(w, st, st[-1] if st else result.status, result.hi)
                answers.seen = []
                try:
                    value = getattr(call.chip, call.name)(*call.args, **call.kwargs)
                except LM629Error as exc:
                    _name_call(exc, f"batch call {i + 1} of {n}, {call.label}")
                    raise
                if [p.ops for p in answers.seen] != [ops]:
                    raise RuntimeError(f"batch call {i + 1} of {n}, {call.label}: its program "
                                       "came out otherwise from the results of the calls "
                                       "before it (the program sent was the first one); run "
                                       "it outside a batch")
                call.handle.resolve(value)

    def __enter__(self) -> Batch:
        self._check_thread("with batch")
        open_here = self._open.transports
        if any(t is self.transport for t in open_here):
            raise RuntimeError(
                f"a batch is already open on {self.transport.describe()} in this thread: queue "
                "these calls on it (its programs would otherwise reach the bus after this "
                "one's), or end its block first")
        open_here.append(self.transport)
        self._entered = True
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if self._entered:
            self._open.transports.remove(self.transport)
            self._entered = False
        if exc_type is None:
            self.run()
        else:  # the block failed: nothing is sent
            self._ran = True


__all__ = ["BATCHABLE", "Batch", "Handle"]
