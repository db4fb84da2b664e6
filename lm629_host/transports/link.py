"""The transport over a bridge that runs whole bus programs on its far side: the host end of
the link protocol (``firmware_bridge/PROTOCOL.md``; its bytes are :mod:`lm629_host.bridge.protocol`).

:class:`Pipe` is the byte stream to a bridge with its own clock (a pyserial port, a simulated
AVR UART, the Python far end, a lossy test wrapper); :class:`LinkTransport` is the transport over
any pipe: handshake on open, one RUN frame per program, typed errors.  ``serial://``,
``sim+avr://`` and ``sim+emu://`` are this transport over their pipes.

The link is split by job: the session core (frames, one request and its answer, retries,
resynchronisation, error rate) is :mod:`.session`, which this class extends with bus programs;
the failsafe (:mod:`.failsafe`), the recorder (:mod:`.recorder`), the PROFILE scheduler
(:mod:`.profiles`), the program-code cache (:mod:`.codes`) and the baud switch (:mod:`.baud`)
are parts it holds.

The bridge answers a repeated RUN (same ``seq`` and CRC) from its cache, so the retries never
run a program twice; after the last retry the host cannot know whether the program ran and
says so.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence

from lm629_host.bridge.protocol.constants import (
    CODE_BYTES,
    FIRMWARE_DEFAULT_BUSY_TIMEOUT_US,
    MAX_FRAME,
    NONE_BYTE,
    PROFILE_MAX_SCHEDULE,
    PROTOCOL_VERSION,
    RUN_OVERHEAD,
    RUN_REPLY_OVERHEAD,
    Capability,
    FrameType,
    Result,
)
from lm629_host.bridge.protocol.failsafe import FailsafeState
from lm629_host.bridge.protocol.framing import Frame, FrameError, wire_size
from lm629_host.bridge.protocol.hello import HelloInfo
from lm629_host.bridge.protocol.pipe import Pipe
from lm629_host.bridge.protocol.run import RunReply, busy_timeout_us, decode_short_reply, encode_program, reply_size, run_payload
from lm629_host.bus.program import (
    OP_ARG_BYTES,
    STATUS_OPS,
    BusOp,
    Op,
    Program,
    ProgramResult,
    TraceCallback,
)
from lm629_host.errors import AxisError, BusyTimeout, LinkError, TransportError
from lm629_host.urls import Option, PortURL
from lm629_host.transports import baud as _baud
from lm629_host.transports.reports import ProfileState, RawRow
from lm629_host.transports.codes import ProgramCodes
from lm629_host.transports.failsafe import FAILSAFE_OPTIONS, FailsafeOptions, LinkFailsafe
from lm629_host.transports.profiles import ProfileScheduler
from lm629_host.transports.recorder import FAR_NOTE, LinkRecorder
from lm629_host.transports.session import (
    DEFAULT_RETRIES,
    LinkSession,
)

log = logging.getLogger("lm629_host.bridge.protocol")

#: PINGs timed after the handshake; the median is the reported round-trip time
RTT_PINGS = 5

#: the URL options every bridge port takes, declared once: a port's table is built from these
#: rows (its own defaults: :func:`~lm629_host.urls.with_defaults`) and adds its own; the
#: failsafe's rows are :data:`~lm629_host.transports.failsafe.FAILSAFE_OPTIONS`
LINK_OPTIONS: tuple[Option, ...] = (
    Option("baud", "int", 115200, 300, 4_000_000, "baud"),
    Option("fast_baud", "int", 0, 300, 4_000_000, "baud", off=0),  # 0: stay at baud
    Option("retries", "int", DEFAULT_RETRIES, 0, 20),
    *FAILSAFE_OPTIONS,
)

#: results by which the bridge refuses a program before running any of it
_REFUSALS = (Result.BAD_PROGRAM, Result.PROGRAM_TOO_LONG, Result.BAD_CHIP_SELECT)


# ---------------------------------------------------------------------------------- transport
class LinkTransport(LinkSession):
    """A transport whose far side is a bridge speaking PROTOCOL.md over a :class:`Pipe`.

    One RUN frame per bus program (programs longer than the bridge takes are split at operation
    boundaries); the exchange, its retries and its errors are :class:`LinkSession`'s.
    """

    scheme = "link"
    #: the bridge firmware's WAIT counts 4 us timer ticks from wherever in a tick it starts,
    #: and decodes the next op before the status strobe: up to 15 us after the wait asked,
    #: measured cycle-exact on the firmware in simavr (RDDP's 20 us busy reads 5 us)
    busy_probe_us = 16.0
    #: how long :meth:`hello` keeps asking before "no answer" (an Uno boots in ~1-2 s after the
    #: port opens; subclasses for real ports raise it)
    hello_total_s: float = 0.5

    def __init__(self, pipe: Pipe, url: str | PortURL, *, trace: TraceCallback | None = None,
                 retries: int = DEFAULT_RETRIES, baud: int | None = None, cs: int = 0,
                 handshake: bool = True, compact: bool = True, fast_baud: int = 0,
                 measure_rtt: bool = True, failsafe: FailsafeOptions | None = None) -> None:
        super().__init__(pipe, url, trace=trace, retries=retries, baud=baud)
        #: use RUN_SHORT where the bridge offers it (False: always RUN, as protocol 1 began)
        self.compact = compact
        self.has_compact_run = False
        self.has_program_codes = False
        self.cs = cs
        self._has_hi = True
        self.codes = ProgramCodes()
        self.failsafe = LinkFailsafe(self, failsafe)
        self.recorder = LinkRecorder(self, self.failsafe)
        self.profiles = ProfileScheduler(self, self.failsafe, cs)
        self.failsafe.on_turn = self._top_up_quietly
        self.rtt_s: float | None = None  #: the measured PING round trip (s), once opened
        #: why the line runs at :attr:`baud` (``lm629 status`` says it)
        self.rate_note = "the handshake rate"
        if handshake:
            try:
                self.open_link(fast_baud, measure_rtt)
            except BaseException:
                self.close()
                raise

    def open_link(self, fast_baud: int = 0, measure_rtt: bool = True) -> None:
        """The open sequence of every bridge port, real or simulated, in this order: HELLO
        until answered; the faster rate (``fast_baud``, SET_BAUD) where the bridge and the
        line can; the round trip measured (``measure_rtt``: :data:`RTT_PINGS` PINGs at the
        rate the link keeps); the failsafe armed last, so that neither the switch nor the
        PINGs are timed by it.  The counters start afterwards, with the first program, as on
        every other transport (the HELLOs a booting bridge left unanswered are not the line's
        error rate either)."""
        self.hello()
        baud = self.baud
        if fast_baud and fast_baud != baud:
            if not getattr(self.pipe, "sets_line_rate", True):
                self.rate_note = (f"the handshake rate: raw TCP cannot set the far UART's rate, "
                                  f"so fast_baud={fast_baud} is not asked for (rfc2217:// can)")
            else:  # a bridge or a line that cannot: a warning, and the link stays
                switched = self.switch_baud(fast_baud)
                self.rate_note = (f"switched from {baud} baud after the handshake" if switched
                                  else f"the handshake rate: the switch to {fast_baud} baud "
                                  "did not take")
        elif not fast_baud:
            self.rate_note = "the handshake rate (fast_baud=0)"
        if measure_rtt:
            self.rtt_s = self.measure_rtt()
            log.info("%s: round trip %.2f ms", self.url, self.rtt_s * 1e3)
        self.failsafe.open()
        self.stats.reset()
        self.attempts.clear()

    def measure_rtt(self, n: int = RTT_PINGS) -> float:
        """Median round trip of ``n`` empty PINGs, seconds (on the link's clock)."""
        # the median taken here, as statistics.median takes it: that module (with fractions and
        # decimal) cost every bridge port's open ~1.5 ms of import
        rtts = sorted(self.ping() for _ in range(n))
        mid = n // 2
        return rtts[mid] if n % 2 else (rtts[mid - 1] + rtts[mid]) / 2

    def line_rate(self) -> tuple[int, str]:
        """The rate the line runs at and why (``lm629 status``'s ``link`` line)."""
        return self.baud or 0, self.rate_note

    def _bridge_forgot(self) -> None:
        self.codes.forget()

    def _top_up_quietly(self) -> None:
        """At a keep-alive's turn: top up a streamed shaped move when no request is under way
        (a host that only sleeps or holds the lock still hands the bridge its pieces)."""
        if (not self.profiles.streaming or self.failsafe.recording
                or not self._rx_lock.acquire(blocking=False)):
            return  # a recording ends at any byte but a feed: the next program tops up
        try:
            self.profiles.refill()
        except (TransportError, OSError) as exc:  # the next program hears it again
            log.debug("%s: PROFILE top-up failed: %s", self.url, exc)
        finally:
            self._rx_lock.release()

    # ------------------------------------------------------------------ the failsafe
    @property
    def failsafe_report(self) -> FailsafeState | None:
        """The trip this open found latched (and acknowledged), or one the feeder saw."""
        return self.failsafe.report

    def feed(self) -> None:
        """Feed the bridge's failsafe now.  With ``failsafe_feed=script`` this and the
        script's own commands are all that feed it; with the default ``process`` a keep-alive
        feeds it anyway, and this changes nothing (docs/python.md, the failsafe)."""
        self.failsafe.feed()

    # ------------------------------------------------------------------ protocol requests
    def hello(self) -> HelloInfo:
        """HELLO until answered (for :attr:`hello_total_s`); check the protocol version."""
        timeout = max(self.hello_interval_s,
                      self.reply_timeout(wire_size(4), wire_size(4 + HelloInfo.SIZE)))
        retries = max(0, round(self.hello_total_s / timeout) - 1)
        frame = self.request(FrameType.HELLO, b"", "HELLO (handshake)",
                             wire_size(4 + HelloInfo.SIZE), retries=retries, resync=False,
                             timeout_s=timeout)
        try:
            info = HelloInfo.decode(frame.payload)
        except FrameError as exc:
            raise TransportError(f"malformed HELLO_REPLY ({exc}): reflash the bridge firmware "
                                 "(lm629 bridge flash)", port=self.url) from None
        if info.protocol != PROTOCOL_VERSION:
            raise TransportError(
                f"the bridge speaks link protocol version {info.protocol}, this host speaks "
                f"version {PROTOCOL_VERSION}. Reflash the bridge with the firmware of this "
                f"host's release: lm629 bridge flash --port {self.url} (or upgrade lm629-host "
                "to match the firmware).", port=self.url)
        if not info.capabilities & Capability.BUSY_ON_BRIDGE:
            raise TransportError("the bridge does not poll busy itself, which protocol 1 "
                                 "requires: reflash the firmware (lm629 bridge flash)",
                                 port=self.url)
        if self.cs >= info.chip_selects:
            raise AxisError(self.cs, info.chip_selects, f"the bridge at {self.url}")
        self.info = info
        self.chip_selects = info.chip_selects
        self.has_reset_line = bool(info.capabilities & Capability.RESET_LINE)
        self._has_hi = bool(info.capabilities & Capability.HI_LINE)
        self.has_wait_status = bool(info.capabilities & Capability.WAIT_STATUS)
        self.has_compact_run = bool(info.capabilities & Capability.COMPACT_RUN) and self.compact
        self.has_program_codes = (self.has_compact_run
                                  and bool(info.capabilities & Capability.PROGRAM_CODES))
        self.recorder.available = bool(info.capabilities & Capability.RECORD)
        self.failsafe.available = bool(info.capabilities & Capability.FAILSAFE)
        self.far_profiles = bool(info.capabilities & Capability.PROFILE)
        self.profile_capacity = PROFILE_MAX_SCHEDULE if self.far_profiles else 0
        self.profile_streams = self.far_profiles
        # a WAIT_STATUS may stand anywhere in a program (Move.wait's one-exchange end check)
        self.far_waits = self.has_wait_status
        return info

    def switch_baud(self, baud: int) -> bool:
        """Ask the bridge to run the line at ``baud`` (:func:`.baud.switch_baud`)."""
        return _baud.switch_baud(self, baud)

    # ------------------------------------------------------------------ the failsafe
    def failsafe_state(self) -> FailsafeState | None:
        """The bridge's failsafe now (armed timeout, action, a latched trip), or None when
        the bridge has no failsafe."""
        return self.failsafe.state()

    def clear_failsafe(self) -> FailsafeState | None:
        """Acknowledge a latched trip and arm the failsafe again (:meth:`LinkFailsafe.clear`)."""
        return self.failsafe.clear()

    # ------------------------------------------------------------------ programs
    def _chunks(self, program: Program) -> Iterator[tuple[int, int, list[BusOp]]]:
        """Split ``program`` at operation boundaries into runs that fit the bridge's limits
        (HELLO_REPLY's largest program and reads, and MAX_FRAME for the reply): usually one.
        Yields (index of the run's first operation in ``program``, chip select, operations).

        Chip selects: the SELECTs at the head of a run become the RUN's ``cs`` field; a SELECT
        inside a run stays in it on a bridge that runs them (Capability.SELECT), and cuts the
        run on an older one (one RUN per chip: correct, one round trip more each)."""
        info = self.info or HelloInfo()
        max_program = min(info.max_program, MAX_FRAME - RUN_OVERHEAD)
        inline = bool(info.capabilities & Capability.SELECT)
        chunk: list[BusOp] = []
        size = reads = n_status = 0
        cs, first = self.cs, 0
        for i, o in enumerate(program.ops):
            if o.op is Op.SELECT:
                if not chunk:
                    cs, first = o.arg, i + 1
                    continue
                if not inline:
                    yield first, cs, chunk
                    chunk, size, reads, n_status = [], 0, 0, 0
                    cs, first = o.arg, i + 1
                    continue
            n = 1 + OP_ARG_BYTES[o.op]
            r = 1 if o.op is Op.READ else 0
            s = 1 if o.op in STATUS_OPS else 0
            if chunk and (size + n > max_program or reads + r > info.max_reads
                          or RUN_REPLY_OVERHEAD + n_status + s + 2 * (reads + r) > MAX_FRAME):
                yield first, cs, chunk
                # the next run starts on the chip the last SELECT of this one chose
                cs = next((p.arg for p in reversed(chunk) if p.op is Op.SELECT), cs)
                chunk, size, reads, n_status = [], 0, 0, 0
                first = i
            chunk.append(o)
            size, reads, n_status = size + n, reads + r, n_status + s
        if chunk or first == 0:
            yield first, cs, chunk

    def _execute(self, program: Program) -> ProgramResult:
        self.failsafe.check()
        if self.profiles.streaming:
            self.profiles.refill()
        timeout_us = busy_timeout_us(program)
        self.resync()
        words: list[int] = []
        statuses: list[int] = []
        status: int | None = None
        hi: bool | None = None
        chip = self.cs
        for base, cs, ops in self._chunks(program):
            if cs != chip:  # a chip select carried in the RUN's cs field: traced as a select
                chip = cs
                self._emit_cycles([BusOp(Op.SELECT, cs)], (), ())
            chip = next((o.arg for o in reversed(ops) if o.op is Op.SELECT), chip)
            reply = self._run(ops, timeout_us, program.busy_timeout_s, cs)
            ok = reply.result == Result.OK
            busy = reply.result == Result.BUSY_TIMEOUT
            # operations that touched the bus: all, those before the failing one and its busy
            # check after a busy timeout, none when the bridge refused the program
            ran = ops if ok else ops[:reply.index + 1] if busy else []
            self._account(ran, reply)
            self._emit_cycles(ops if ok else ops[:reply.index] if busy else [], reply.words,
                              reply.statuses)
            words += reply.words
            statuses += reply.statuses
            if reply.last_status != NONE_BYTE or any(o.op not in (Op.WAIT, Op.RESET) for o in ran):
                status = reply.last_status
            hi = bool(reply.hi) if self._has_hi else None
            if not ok:
                self._raise_result(reply, ops, base, program, words)
        return ProgramResult(tuple(words), tuple(statuses), status, hi)

    def _run(self, ops: list[BusOp], timeout_us: int, timeout_s: float,
             cs: int | None = None, refused_once: bool = False) -> RunReply:
        chip = self.cs if cs is None else cs
        # the compact form where the bridge takes it and the fields it leaves out are the
        # defaults (starting on chip select 0, the firmware's busy timeout): 5 fewer bytes a
        # round trip
        short = (self.has_compact_run and chip == 0
                 and timeout_us == FIRMWARE_DEFAULT_BUSY_TIMEOUT_US)
        store: tuple[bytes, int] | None = None
        if short:
            ftype, payload = FrameType.RUN_SHORT, encode_program(ops)
            if self.has_program_codes and len(payload) <= CODE_BYTES:
                ftype, payload, store = self.codes.choose(payload)
        else:
            ftype, payload = FrameType.RUN, run_payload(ops, timeout_us, chip)
        req = wire_size(len(payload) + 4)
        rep = wire_size(reply_size(ops))  # a RUN_REPLY (a failure) is the longer answer
        timeout = self.reply_timeout(req, rep, ops, timeout_s)
        decoded: list[RunReply] = []

        def check(frame: Frame) -> None:
            if frame.type == FrameType.RUN_SHORT_REPLY:
                decoded.append(decode_short_reply(frame.payload, ops))  # FrameError: retried
                return
            reply = RunReply.decode(frame.payload)  # FrameError: retried
            if reply.result in (Result.OK, Result.BUSY_TIMEOUT):
                done = len(ops) if reply.result == Result.OK else min(reply.index, len(ops))
                want_words = sum(1 for o in ops[:done] if o.op is Op.READ)
                want_status = sum(1 for o in ops[:done] if o.op in STATUS_OPS)
                if len(reply.words) != want_words or len(reply.statuses) != want_status:
                    raise FrameError(
                        f"RUN_REPLY carries {len(reply.statuses)} status byte(s) and "
                        f"{len(reply.words)} word(s), expected {want_status} and {want_words}")
            decoded.append(reply)

        self._exchange(ftype, payload, timeout, f"RUN of {len(ops)} operation(s)",
                       self.retries, check)
        reply = decoded[-1]
        if ftype is FrameType.RUN_CODE and reply.result == Result.UNKNOWN_CODE:
            # the bridge lost its codes (it restarted without the host seeing a HELLO):
            # nothing ran; forget them all and send the program itself
            log.info("%s: the bridge keeps no program under code %d: sending it again",
                     self.url, payload[0])
            self.codes.forget()
            return self._run(ops, timeout_us, timeout_s, cs)
        if reply.result in _REFUSALS and not refused_once:
            # The bridge refused the program and ran none of it.  This host built a program
            # the bridge's HELLO limits allow, so on a noisy line the likely cause is a request
            # damaged in a way its CRC-16 let through (PROTOCOL.md, error-detection budget):
            # send it once more, a new exchange, before blaming the firmware.  Safe: nothing ran.
            self.stats.retries += 1
            log.info("%s: the bridge refused a program it should take (%s): sending it again",
                     self.url, Result(reply.result).name)
            return self._run(ops, timeout_us, timeout_s, cs, refused_once=True)
        if store is not None and reply.result == Result.OK:
            self.codes.remember(*store)
        # a refused program (BAD_PROGRAM...) is raised by the caller, whatever it carries
        return reply

    def _raise_result(self, reply: RunReply, ops: list[BusOp], base: int, program: Program,
                      words: list[int]) -> None:
        index = reply.index
        op = ops[index].describe() if index < len(ops) else f"operation {index}"
        where = f" at operation {base + index} ({op})" if index < len(ops) else ""
        if reply.result == Result.FAILSAFE_TRIPPED:
            raise self.failsafe.tripped_error("nothing of this program ran")
        if reply.result == Result.BUSY_TIMEOUT:
            # a busy timeout always read the status, so FF here is a status (a bus no chip
            # drives), not the "no status" byte
            raise BusyTimeout(op, program.busy_timeout_s, reply.last_status, base + index, words)
        try:
            name = Result(reply.result).name
        except ValueError:
            name = f"unknown result {reply.result}"
        # refused twice (see _run): nothing of this part ran; earlier parts of a program cut
        # into several RUNs (base > 0) did
        raise LinkError(
            f"the bridge refused the program{where} twice: {name}; nothing of it ran. "
            "Host and firmware disagree on the program format or limits; reflash the firmware "
            "that matches this host (lm629 bridge flash).", port=self.url,
            may_have_run=base > 0)

    # ------------------------------------------------------------------ shaped moves (PROFILE)
    def profile(self, axis: int | None, pieces: Sequence[tuple[float, int]], *,
                new: bool) -> ProfileState:
        """PROFILE frames: :meth:`.profiles.ProfileScheduler.send`."""
        if not self.far_profiles:
            return super().profile(axis, pieces, new=new)
        return self.profiles.send(axis, pieces, new=new)

    # ------------------------------------------------------------------ recording (RECORD)
    @property
    def records_on_far_side(self) -> bool:
        """Only with RECORD: without it every row is a host exchange, stamped when it starts
        (in simulated time too)."""
        return self.recorder.available

    def record_note(self) -> str:
        if self.recorder.available:
            return FAR_NOTE
        return super().record_note()

    def record_max_rate(self, program: Program) -> float | None:
        if not self.recorder.available:
            return super().record_max_rate(program)
        return self.recorder.max_rate(program)

    def record_rows(self, program: Program, period_s: float, rows: int) -> Iterator[RawRow]:
        """RECORD on the bridge's timer (:meth:`.recorder.LinkRecorder.rows`), or the host's
        polling where the bridge has no RECORD."""
        if not self.recorder.available:
            yield from super().record_rows(program, period_s, rows)
            return
        yield from self.recorder.rows(program, period_s, rows)

    # ------------------------------------------------------------------ misc
    def describe(self) -> str:
        if self.info is None:
            return self.url
        rtt = f", round trip {self.rtt_s * 1e3:.2f} ms" if self.rtt_s is not None else ""
        return f"{self.url} ({self.info.describe()}){rtt}"

    def close(self) -> None:
        """Disarm the failsafe (a clean close: an axis left moving on purpose keeps moving),
        then release the port."""
        if not self._closed:
            self.failsafe.close()
            self._closed = True
            self.pipe.close()


__all__ = ["LinkTransport"]
