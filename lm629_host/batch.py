"""Several typed calls as one bus program: :meth:`LM629.batch <lm629_host.LM629.batch>`.

Why: on a bridge every program is an exchange, and behind USB an exchange costs what the
adapter makes it cost (4.096 ms on an Uno), so ten calls cost ten exchanges.  A batch queues
the calls and sends their programs as one when the ``with`` block ends: one exchange.

How, without a second copy of each command's encoding: each call is made on the chip at once,
with the bus replaced by a collector that keeps its program and answers it as a chip that
raised no flag would (words 0, status 00); the chip object's own state (the derivative byte,
whether the command-error flag is known clear...) is then put back.  When the block ends the
programs run as one, and every call is made again, in order, from the same state, its bus
answered with its own share of the real results: each method decodes its words and checks its
statuses exactly as it does outside a batch (``start`` raises :class:`CommandError` when its
STT is refused), and that return value is the handle's ``.value``.  An error names the call
("batch call 3 of 10, start()").  A call whose program would differ on the second pass (the
state it depends on came out otherwise) is an error too: it never runs a program other than the
one sent.

Only calls that are one bus program can be queued (:data:`BATCHABLE`); ``reset``, waits and
moves that read before they start are not.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Generic, Protocol, TypeVar

from .errors import LM629Error
from .program import STATUS_OPS, Op, Program, ProgramResult
from .transports.base import Transport

T = TypeVar("T")


class BatchChip(Protocol):
    """What a batch needs of its chip (an :class:`~lm629_host.LM629`; declared here so that
    this module does not import the typed layer back)."""

    transport: Transport
    _run_hook: Callable[[Program], ProgramResult] | None

    def program(self) -> Program: ...

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
    method: Callable[..., Any]
    args: tuple[Any, ...]
    kwargs: dict[str, Any]
    program: Program
    handle: Handle[Any]
    first: int = 0  #: index of its first operation in the batch's program
    result: ProgramResult = field(default_factory=ProgramResult)


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


def _state(chip: BatchChip) -> dict[str, Any]:
    return {k: v for k, v in vars(chip).items() if k.startswith("_") and k != "_run_hook"}


class Batch:
    """Typed calls queued on a chip (see the module doc); use it as a context manager."""

    def __init__(self, chip: BatchChip) -> None:
        self.chip = chip
        self.calls: list[_Call] = []
        self._state = _state(chip)
        self._ran = False

    def __getattr__(self, name: str) -> Callable[..., Handle[Any]]:
        if name not in BATCHABLE:
            raise AttributeError(f"{name} cannot be queued in a batch (one bus program each "
                                 f"only: {', '.join(sorted(BATCHABLE))})")
        method = getattr(self.chip, name)

        def queue(*args: Any, **kwargs: Any) -> Handle[Any]:
            return self._queue(name, method, args, kwargs)
        return queue

    def _queue(self, name: str, method: Callable[..., Any], args: tuple[Any, ...],
               kwargs: dict[str, Any]) -> Handle[Any]:
        if self._ran:
            raise RuntimeError("this batch has run already: start a new one")
        chip = self.chip
        shown = [repr(a) for a in args] + [f"{k}={v!r}" for k, v in kwargs.items()]
        label = f"{name}({', '.join(shown)})"
        programs: list[Program] = []

        def collect(program: Program) -> ProgramResult:
            programs.append(program)
            return _dummy(program)
        chip._run_hook = collect
        try:
            method(*args, **kwargs)  # ValueError for bad arguments: raised here, nothing queued
        except LM629Error:
            pass  # an error from the dummy answer: the real one will tell
        finally:
            chip._run_hook = None
        if len(programs) != 1:
            raise TypeError(f"{label} ran {len(programs)} bus programs: a batch takes one each")
        handle: Handle[Any] = Handle(label)
        self.calls.append(_Call(label, method, args, kwargs, programs[0], handle))
        return handle

    def run(self) -> None:
        """Run the queued calls as one program, then set every handle (raising the first
        call's error, which names the call)."""
        if self._ran:
            return
        self._ran = True
        chip = self.chip
        for k, v in self._state.items():  # back to the state the calls were queued from
            setattr(chip, k, v)
        if not self.calls:
            return
        whole = chip.program()
        whole.ops.clear()  # each call's program carries its own chip select
        for call in self.calls:
            call.first = len(whole.ops)
            whole.extend(call.program)
        n = len(self.calls)
        try:
            result = chip.transport.execute(whole)
        except LM629Error as exc:
            index = getattr(exc, "index", None)
            which = next((i for i, c in reversed(list(enumerate(self.calls)))
                          if isinstance(index, int) and c.first <= index), None)
            if which is not None:
                _name_call(exc, f"batch call {which + 1} of {n}, {self.calls[which].label}")
            raise
        words, statuses = iter(result.words), iter(result.statuses)
        for i, call in enumerate(self.calls):
            ops = call.program.ops
            w = tuple(next(words) for o in ops if o.op is Op.READ)
            st = tuple(next(statuses) for o in ops if o.op in STATUS_OPS)
            share = ProgramResult(w, st, st[-1] if st else result.status, result.hi)
            seen: list[Program] = []

            def answer(program: Program, share: ProgramResult = share,
                       seen: list[Program] = seen) -> ProgramResult:
                seen.append(program)
                return share
            chip._run_hook = answer
            try:
                value = call.method(*call.args, **call.kwargs)
            except LM629Error as exc:
                _name_call(exc, f"batch call {i + 1} of {n}, {call.label}")
                raise
            finally:
                chip._run_hook = None
            if [p.ops for p in seen] != [ops]:
                raise RuntimeError(f"batch call {i + 1} of {n}, {call.label}: its program came "
                                   "out otherwise from the results of the calls before it "
                                   "(the program sent was the first one); run it outside a "
                                   "batch")
            call.handle._value, call.handle._done = value, True

    def __enter__(self) -> Batch:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is None:
            self.run()
        else:  # the block failed: nothing is sent, the chip's state as before
            for k, v in self._state.items():
                setattr(self.chip, k, v)
            self._ran = True


__all__ = ["BATCHABLE", "Batch", "Handle"]
