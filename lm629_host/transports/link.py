"""The transport over a bridge that runs whole bus programs on its far side: the host end of
the link protocol (``firmware_bridge/PROTOCOL.md``; its bytes are :mod:`lm629_host.bridge.protocol`).

:class:`Pipe` is the byte stream to a bridge with its own clock (a pyserial port, a simulated
AVR UART, the Python far end, a lossy test wrapper); :class:`LinkTransport` is the transport over
any pipe: handshake on open, one RUN frame per program, retries with the same ``seq``, typed
errors.  ``serial://``, ``sim+avr://`` and ``sim+emu://`` are this transport over their pipes.

The bridge answers a repeated RUN (same ``seq`` and CRC) from its cache, so the retries here
never run a program twice; after the last retry the host cannot know whether the program ran
and says so.
"""

from __future__ import annotations

import logging
import random
import threading
from collections import OrderedDict, deque
from collections.abc import Callable, Iterator, Sequence
from typing import cast

from lm629_host.bridge.protocol import (
    ALSO_REPLY_TO,
    BAUD_WINDOW_MS,
    CODE_BYTES,
    CODE_SLOTS,
    END_PAYLOAD,
    FAILSAFE_FEED,
    FAILSAFE_MAX_MS,
    FAILSAFE_MIN_MS,
    FIRMWARE_DEFAULT_BUSY_TIMEOUT_US,
    RECORD_MIN_PERIOD_US,
    RECORD_TICK_US,
    ROW_HEADER,
    RUN_TYPES,
    decode_short_reply,
    encode_program,
    MAX_FRAME,
    MAX_PING,
    NONE_BYTE,
    PROFILE_MAX_PIECES,
    PROFILE_MAX_SCHEDULE,
    PROFILE_REPLY_PAYLOAD,
    PROTOCOL_VERSION,
    REPLY_TO,
    RUN_OVERHEAD,
    RUN_REPLY_OVERHEAD,
    Capability,
    Frame,
    FrameError,
    FrameReader,
    FrameType,
    FailsafeAction,
    FailsafeCmd,
    FailsafeState,
    HelloInfo,
    Pipe,
    Result,
    RunReply,
    BadProgram,
    busy_timeout_us,
    check_record_program,
    encode_frame,
    profile_payload,
    record_payload,
    row_wire_bytes,
    reply_size,
    run_payload,
    wire_size,
)
from lm629_host.errors import AxisError, BusyTimeout, TransportError
from lm629_host.bus.program import (
    OP_ARG_BYTES,
    STATUS_OPS,
    BusOp,
    Op,
    Program,
    ProgramResult,
    TraceCallback,
    cycles_of,
)
from lm629_host.clock import WallClock
from lm629_host.urls import Option, PortURL, parse_options, query_params
from lm629_host.transports.base import ProfileState, RawRow, Transport

log = logging.getLogger("lm629_host.bridge.protocol")

#: retries of one request (same ``seq``, same bytes) before the host gives up.  Seven: at 1 % of
#: bytes faulty (each of drop, corrupt, duplicate, delay at 0.25 %) one attempt of a small RUN
#: fails about one time in five, so 3 retries leave ~0.15 % of commands failed, 7 leave none
#: measured in 100,000 (docs/bridge.md); a dead link costs 8 timeouts to notice
DEFAULT_RETRIES = 7
#: how many recent attempts :attr:`LinkTransport.error_rate` looks back over
ERROR_WINDOW = 200
#: an error rate above this makes a give-up message call the link too bad to use
BAD_LINK_RATE = 0.2
#: above this error rate (over a full window) the link logs one warning per window, even while
#: the retries still hide every failure: 5 % of exchanges failing is a cable to look at
WARN_LINK_RATE = 0.05


#: the failsafe's URL options, taken by every bridge port (``failsafe=0``: disarmed)
FAILSAFE_DEFAULT_S = 0.5
FAILSAFE_OPTIONS = (
    Option("failsafe", "float", FAILSAFE_DEFAULT_S, 0, FAILSAFE_MAX_MS / 1e3, "s"),
    Option("failsafe_action", "str", "abrupt", choices=tuple(a.name.lower() for a in FailsafeAction)))
FAILSAFE_OPTION_NAMES = frozenset(o.name for o in FAILSAFE_OPTIONS)
#: the feeder sends when the link has been idle this fraction of the failsafe's timeout: three
#: feeds may be lost on the line before the bridge trips
FEED_FRACTION = 0.25


def failsafe_options(url: str | PortURL) -> tuple[float, FailsafeAction]:
    """``failsafe=SECONDS`` (0: off, else 0.05..10) and ``failsafe_action=abrupt|smooth|off``
    of a bridge port's URL; ValueError naming the option (the other options are not looked at)."""
    opts = parse_options(url, FAILSAFE_OPTIONS,
                         ignore=set(query_params(url)) - FAILSAFE_OPTION_NAMES)
    seconds = opts["failsafe"]
    if seconds and round(seconds * 1e3) < FAILSAFE_MIN_MS:
        raise ValueError(f"{url}: failsafe={seconds:g} is outside 0 (off) or "
                         f"{FAILSAFE_MIN_MS / 1e3:g}..{FAILSAFE_MAX_MS / 1e3:g} s")
    return seconds, FailsafeAction[opts["failsafe_action"].upper()]


class FailsafeTripped(TransportError):
    """The bridge refused a trajectory command: its failsafe tripped (the host was silent past
    the timeout) and no host acknowledged it yet.  ``state``: the latched trip."""

    def __init__(self, message: str, *, port: str, state: FailsafeState | None) -> None:
        super().__init__(message, port=port)
        self.state = state


class LinkError(TransportError):
    """The link gave up on a request.  ``may_have_run``: True when the request may have reached
    the bridge (its program may or may not have run), False when nothing was sent to the chip
    (the resynchronising HELLO before it got no answer)."""

    def __init__(self, message: str, *, port: str, may_have_run: bool) -> None:
        super().__init__(message, port=port)
        self.may_have_run = may_have_run


_BUSY_CHECKED = (Op.COMMAND, Op.WRITE, Op.READ, Op.SYNC)
#: requests sent after a lone delimiter from their first attempt on (a retry always is): the
#: first contact, when the far end may hold half a frame of whoever had the port before, and
#: RECORD, which starts where a recording may still be streaming (a byte ends it)
_DELIMITED = frozenset({FrameType.HELLO, FrameType.RECORD})
#: results by which the bridge refuses a program before running any of it
_REFUSALS = (Result.BAD_PROGRAM, Result.PROGRAM_TOO_LONG, Result.BAD_CHIP_SELECT)


# ---------------------------------------------------------------------------------- transport
class LinkTransport(Transport):
    """A transport whose far side is a bridge speaking PROTOCOL.md over a :class:`Pipe`.

    One RUN frame per bus program (programs longer than the bridge takes are split at operation
    boundaries).  The reply timeout is computed per request (:meth:`reply_timeout`).  On a
    timeout or a bad frame the same frame is sent again, ``retries`` times at most; replies
    with another ``seq`` (late answers to earlier attempts) are ignored.
    """

    scheme = "link"
    #: added to every reply timeout: the far end's own processing time and the latency of a
    #: USB serial adapter (a simulated pipe may lower it: its latency is known)
    margin_s: float = 0.05
    #: bits on the wire per byte for the timeout estimate: start + 8 data + stop (a simulated
    #: UART with two stop bits sets 11)
    wire_bits: int = 10
    #: how long :meth:`hello` keeps asking before "no answer" (an Uno boots in ~1-2 s after the
    #: port opens; subclasses for real ports raise it)
    hello_total_s: float = 0.5
    #: the wait for one HELLO_REPLY before HELLO is sent again
    hello_interval_s: float = 0.1

    def __init__(self, pipe: Pipe, url: str | PortURL, *, trace: TraceCallback | None = None,
                 retries: int = DEFAULT_RETRIES, baud: int | None = None, cs: int = 0,
                 handshake: bool = True, compact: bool = True, arm: bool = True) -> None:
        super().__init__(url, trace=trace)
        if retries < 0:
            raise ValueError(f"retries={retries} must be >= 0")
        if baud is not None and baud <= 0:
            raise ValueError(f"baud={baud} must be a positive number of bits per second")
        self.pipe = pipe
        self.clock = pipe.clock
        #: use RUN_SHORT where the bridge offers it (False: always RUN, as protocol 1 began)
        self.compact = compact
        self.has_compact_run = False
        self.has_program_codes = False
        #: the bridge records on its own timer (RECORD, capability bit 8)
        self.has_record = False
        #: short programs the bridge keeps, by code (RUN_CODE), least recently used first
        self._codes: OrderedDict[bytes, int] = OrderedDict()
        #: short programs sent lately (the second time, one gets a code)
        self._recent: OrderedDict[bytes, None] = OrderedDict()
        self.retries = retries
        self.baud = baud
        self.cs = cs
        self.info: HelloInfo | None = None
        self._seq = random.randrange(256)
        self._reader = FrameReader()
        self._closed = False
        self._has_hi = True
        #: bad frames and stale replies seen (for the fault tests and ``doctor``)
        self.bad_frames = 0
        self.stale_replies = 0
        self.timeouts = 0  #: attempts that got no (usable) answer in time
        #: the last ERROR_WINDOW attempts, True for each that failed (bad frame or no answer)
        self._attempts: deque[bool] = deque(maxlen=ERROR_WINDOW)
        #: a request was given up: the bridge's cache may still hold its seq, so the next
        #: request is preceded by a HELLO (which empties that cache) -- see :meth:`_resync`
        self._need_resync = False
        self._since_warning = 0  #: attempts since the last link-quality warning
        #: the failsafe asked for by the URL (seconds, 0: off) and its action
        self.failsafe_s, self.failsafe_action = failsafe_options(url)
        self.has_failsafe = False
        #: the trip this open found latched (and acknowledged), or one the feeder saw
        self.failsafe_report: FailsafeState | None = None
        #: the feeder sends after the link was idle this long (0: no feeder)
        self.feed_period_s = 0.0
        self._last_tx = self.clock.now()
        self._feeder: threading.Thread | None = None
        self._feeder_stop = threading.Event()
        self._tx_lock = threading.Lock()  # the feeder writes a recording's feed from its thread
        self._recording = False
        if handshake:
            try:
                self.hello()
                if arm:  # else the subclass arms once its own opening steps are done
                    self._failsafe_open()
            except BaseException:
                self.close()
                raise
            # the counters start with the first program, as on every other transport (the
            # HELLOs a booting bridge left unanswered are not the line's error rate either)
            self.stats.reset()
            self._attempts.clear()

    # ------------------------------------------------------------------ helpers
    def _next_seq(self) -> int:
        self._seq = (self._seq + 1) & 0xFF
        return self._seq

    def _byte_s(self) -> float:
        return self.wire_bits / self.baud if self.baud else 0.0

    def reply_timeout(self, request_wire: int, reply_wire: int, ops: Sequence[BusOp] = (),
                      timeout_s: float = 0.0) -> float:
        """Wire time of request and reply at the baud rate, plus ``timeout_s`` for every
        busy-checked operation, plus the program's WAITs, plus :attr:`margin_s`."""
        t = (request_wire + reply_wire) * self._byte_s() + self.margin_s
        for o in ops:
            if o.op in _BUSY_CHECKED:
                t += timeout_s
            elif o.op is Op.WAIT:
                t += o.arg * 1e-6
            elif o.op is Op.WAIT_STATUS:  # the wait, each poll period a little late, + 10 ms
                t += (o.arg & 0xFFFF) * 1e-3 * 1.1 + 0.01
        return t

    def _no_answer(self, what: str, attempts: int) -> TransportError:
        return TransportError(
            f"no answer to {what} after {attempts} attempt(s). Check that the bridge firmware "
            f"is flashed (lm629 bridge flash --port {self.url}), that the baud rate matches the "
            "firmware's, and that nothing else holds the port.", port=self.url)

    # ------------------------------------------------------------------ link quality
    @property
    def error_rate(self) -> float:
        """Fraction of the last :data:`ERROR_WINDOW` attempts that failed (a bad frame, or no
        usable answer in time): the line's health as the host sees it."""
        a = self._attempts
        return sum(a) / len(a) if a else 0.0

    def _attempt(self, failed: bool) -> None:
        """Count one attempt; warn (once per window) when the line is bad, before it costs a
        command."""
        self._attempts.append(failed)
        self._since_warning += 1
        if (self._since_warning >= ERROR_WINDOW and len(self._attempts) == ERROR_WINDOW
                and self.error_rate >= WARN_LINK_RATE):
            self._since_warning = 0
            log.warning("%s: %s", self.url, self._quality())

    def _quality(self) -> str:
        """One sentence on the measured link quality and what to check."""
        a = self._attempts
        failed, n = sum(a), len(a)
        rate = failed / n if n else 0.0
        verdict = ("the link is too noisy to use: " if rate >= BAD_LINK_RATE
                   else "link quality: ")
        return (f"{verdict}{failed} of the last {n} exchanges failed ({100 * rate:.0f} %; "
                f"{self.bad_frames} bad frame(s), {self.timeouts} timeout(s) since open). "
                "Check the USB cable (short, shielded, away from motor and amplifier wiring), "
                "the ground between the bridge and the LM629 board, and that the baud rate "
                f"matches the firmware's ({self.baud or '?'} here)")

    # ------------------------------------------------------------------ exchanges
    def _exchange(self, ftype: FrameType, payload: bytes, timeout_s: float, what: str,
                  retries: int, check: Callable[[Frame], object] | None = None,
                  pending: deque[Frame] | None = None) -> Frame:
        """Send one request and return its (first) reply, retrying with the same frame.

        ``check(frame)`` may raise :class:`FrameError` for a reply that passed its CRC but
        cannot be the answer (wrong length for the program): that is line damage the CRC
        missed, and the request is sent again (the bridge answers from its cache).

        RECORD is never answered from the cache: each attempt is a new request with a new
        ``seq`` (the reply's ``seq`` says which), so that rows of an attempt the bridge did
        start are told apart and ignored; its further replies (rows that came in the same
        read) wait in ``pending``."""
        fresh = ftype is FrameType.RECORD
        seq = self._next_seq()
        wire = encode_frame(ftype, seq, payload)
        want = REPLY_TO[ftype]
        stats = self.stats
        clock = self.clock
        attempts = 0
        bad_before = self.bad_frames
        for attempt in range(retries + 1):
            if attempt:
                stats.retries += 1
                if fresh:
                    seq = self._next_seq()
                    wire = encode_frame(ftype, seq, payload)
                log.info("%s: retry %d of %s seq %d", self.url, attempt, what, seq)
            attempts += 1
            # before a retry, a lone delimiter ends whatever half frame the far end holds (and
            # a recording under way: any byte from the host ends one)
            out = b"\x00" + wire if attempt or ftype in _DELIMITED else wire
            self._last_tx = clock.now()
            self.pipe.write(out)
            stats.bytes_out += len(out)
            stats.round_trips += 1
            deadline = clock.now() + timeout_s
            if pending is not None:
                pending.clear()
            frame = self._await(seq, deadline, pending)
            if frame is None:
                self._attempt(True)
                continue
            if frame.type == FrameType.ERROR_REPLY:
                code = frame.payload[0] if frame.payload else -1
                raise TransportError(
                    f"the bridge refused {what} (ERROR_REPLY, code {code}): the host and the "
                    "firmware disagree on the protocol. Reflash the firmware that matches this "
                    "host (lm629 bridge flash).", port=self.url)
            if frame.type != want and frame.type != ALSO_REPLY_TO.get(ftype):
                raise TransportError(
                    f"the bridge answered {what} with frame type {frame.type:02X}, expected "
                    f"{int(want):02X}: reflash the firmware that matches this host "
                    "(lm629 bridge flash).", port=self.url)
            if check is not None:
                try:
                    check(frame)
                except FrameError as exc:
                    self.bad_frames += 1
                    self._attempt(True)
                    log.debug("%s: reply to %s passed its CRC but is malformed: %s", self.url,
                              what, exc)
                    continue
            self._attempt(False)
            return frame
        if ftype is FrameType.HELLO:
            raise self._no_answer(what, attempts)
        self._need_resync = True  # the bridge may hold this seq in its cache
        if fresh:  # the bridge answered HELLO: the line, not the firmware, is the suspect
            raise LinkError(f"no answer to {what} after {attempts} attempt(s): "
                            f"{self._quality()}", port=self.url, may_have_run=True)
        if ftype not in RUN_TYPES:
            raise self._no_answer(what, attempts)
        raise LinkError(
            f"no valid answer to {what} after {attempts} attempt(s) "
            f"({self.bad_frames - bad_before} bad frame(s)): the program may or may not "
            f"have run on the chip; {self._quality()}; then reset the chip (LM629.reset) "
            "before going on.", port=self.url, may_have_run=True)

    def _await(self, seq: int, deadline: float, pending: deque[Frame] | None = None, *,
               bad_ends_wait: bool = True, feed: bool = False) -> Frame | None:
        """The next reply with ``seq``, or None at ``deadline`` (a timeout) or, with
        ``bad_ends_wait``, on a bad frame: the far end does not answer a request it could not
        read, so a request calls for a retry at once.  A recording's rows come several in one
        read: the ones after the first wait in ``pending`` (taken first by the next call);
        without ``pending`` a request has one reply and the rest are dropped.  With ``feed``
        (a recording with the failsafe armed) the wait is read in feed periods, each begun
        with a FAILSAFE_FEED when one is due."""
        if pending:
            return pending.popleft()
        queue: deque[Frame] = pending if pending is not None else deque()
        clock = self.clock
        while True:
            if feed:
                self._feed_recording()
            left = deadline - clock.now()
            if left <= 0:
                self.timeouts += 1
                return None
            data = self.pipe.read(min(left, self.feed_period_s) if feed else left)
            if not data:
                if feed and clock.now() < deadline:
                    continue
                self.timeouts += 1
                return None
            self.stats.bytes_in += len(data)
            bad = False
            for item in self._reader.feed(data):
                if isinstance(item, FrameError):
                    self.bad_frames += 1
                    log.debug("%s: bad frame: %s", self.url, item)
                    bad = True
                elif item.seq != seq or item.type & 0x80 == 0:
                    self.stale_replies += 1
                    log.debug("%s: ignored frame type %02X seq %d (waiting for %d)",
                              self.url, item.type, item.seq, seq)
                else:
                    queue.append(item)
            if queue:
                return queue.popleft()
            if bad and bad_ends_wait:
                return None

    def _resync(self) -> None:
        """After a request was given up, HELLO before the next one.

        The bridge answers a RUN whose seq and CRC equal its cached ones from the cache.  The
        seq wraps at 256, so after a give-up (the bridge may hold that request's reply) a
        later request with the same bytes could come round to the same seq while nothing in
        between reached the bridge (a cable out for 256 calls of a polling loop): it would be
        answered from the cache and never run.  HELLO empties the cache; until a HELLO is
        answered, no request is sent at all (so those failures are certain: nothing ran)."""
        if not self._need_resync:
            return
        timeout = max(self.hello_interval_s,
                      self.reply_timeout(wire_size(4), wire_size(4 + HelloInfo.SIZE)))
        try:
            self._exchange(FrameType.HELLO, b"", timeout, "HELLO (resynchronising after a "
                           "failed exchange)", self.retries)
        except TransportError:
            raise LinkError(
                "no answer from the bridge since the last failed exchange (HELLO unanswered "
                f"{self.retries + 1} times): nothing was sent to the chip; {self._quality()}.",
                port=self.url, may_have_run=False) from None
        self._need_resync = False
        self._forget_codes()  # HELLO emptied the bridge's codes

    # ------------------------------------------------------------------ protocol requests
    def hello(self) -> HelloInfo:
        """HELLO until answered (for :attr:`hello_total_s`); check the protocol version."""
        timeout = max(self.hello_interval_s,
                      self.reply_timeout(wire_size(4), wire_size(4 + HelloInfo.SIZE)))
        retries = max(0, round(self.hello_total_s / timeout) - 1)
        frame = self._exchange(FrameType.HELLO, b"", timeout, "HELLO (handshake)", retries)
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
        self.has_record = bool(info.capabilities & Capability.RECORD)
        self.has_failsafe = bool(info.capabilities & Capability.FAILSAFE)
        self.far_profiles = bool(info.capabilities & Capability.PROFILE)
        self.profile_capacity = PROFILE_MAX_SCHEDULE if self.far_profiles else 0
        # a WAIT_STATUS may stand anywhere in a program (Move.wait's one-exchange end check)
        self.far_waits = self.has_wait_status
        self._forget_codes()  # HELLO empties the bridge's codes
        return info

    def ping(self, data: bytes = b"") -> float:
        """PING with ``data`` echoed; returns the round-trip time on the pipe's clock."""
        if len(data) > MAX_PING:
            raise ValueError(f"ping payload of {len(data)} bytes is longer than {MAX_PING}")
        self._resync()
        t0 = self.clock.now()
        n = 4 + len(data)
        frame = self._exchange(FrameType.PING, data,
                               self.reply_timeout(wire_size(n), wire_size(n)), "PING",
                               self.retries)
        if frame.payload != data:
            raise TransportError("PONG does not echo the PING payload: the link corrupts data "
                                 "that passes its CRC; check the baud rate", port=self.url)
        return self.clock.now() - t0

    def switch_baud(self, baud: int) -> bool:
        """Ask the bridge to run the line at ``baud`` (SET_BAUD; the pipe must have
        ``set_baud``).  True when the link runs at it now.  False when it stays at the rate it
        had, with a warning that says why: a bridge without BAUD_SWITCH (then nothing is
        sent), a rate the bridge cannot make, or no answer at the new rate (a USB serial
        adapter that cannot do it): then the bridge goes back by itself after
        BAUD_WINDOW_MS, and so does the host.  A failure to talk at either rate afterwards is
        a :class:`TransportError`."""
        set_baud = getattr(self.pipe, "set_baud", None)
        info = self.info
        if (set_baud is None or info is None or not info.capabilities & Capability.BAUD_SWITCH
                or baud == self.baud):
            return False
        old = self.baud
        self._resync()
        try:
            frame = self._exchange(
                FrameType.SET_BAUD, baud.to_bytes(4, "big"),
                self.reply_timeout(wire_size(8), wire_size(9)), f"SET_BAUD {baud}", self.retries)
            result = frame.payload[0] if frame.payload else -1
        except TransportError:
            result = None  # the bridge may or may not have switched: wait its window out
        if result == Result.OK:
            set_baud(baud)
            self.baud = baud
            # three HELLOs at the new rate, all within the bridge's window
            tries = 3
            hello_s = max(self.reply_timeout(wire_size(4), wire_size(4 + HelloInfo.SIZE)),
                          BAUD_WINDOW_MS * 1e-3 * 0.6 / tries)
            try:
                self._exchange(FrameType.HELLO, b"", hello_s, f"HELLO at {baud} baud",
                               tries - 1)
            except TransportError:
                pass
            else:
                self._forget_codes()
                log.info("%s: the link runs at %d baud", self.url, baud)
                return True
            why = f"no answer at {baud} baud (can the USB serial adapter do it?)"
        elif result is None:
            why = "no answer to SET_BAUD"
        else:
            why = f"the bridge cannot make {baud} baud (result {result})"
        # back to the old rate; the bridge goes back too once its window has passed
        set_baud(old)
        self.baud = old
        if result is None or result == Result.OK:  # else the bridge never left the old rate
            self.clock.sleep(BAUD_WINDOW_MS * 1e-3 * 1.2)
        self._need_resync = True  # HELLO at the old rate before anything else
        try:
            self._resync()
        except TransportError:
            if result != Result.OK:
                raise
            # its answer to our HELLO at the new rate may have been lost, so that it stayed
            set_baud(baud)
            self.baud = baud
            self._need_resync = True
            self._resync()
            log.info("%s: the link runs at %d baud", self.url, baud)
            return True
        log.warning("%s: staying at %d baud: %s", self.url, old, why)
        return False

    # ------------------------------------------------------------------ the failsafe
    def _failsafe(self, payload: bytes, what: str, retries: int | None = None) -> FailsafeState:
        """One FAILSAFE exchange; its reply's state (TransportError when it is refused)."""
        self._resync()
        frame = self._exchange(FrameType.FAILSAFE, payload, self.reply_timeout(
            wire_size(4 + len(payload)), wire_size(4 + FailsafeState.SIZE)), what,
            self.retries if retries is None else retries)
        try:
            state = FailsafeState.decode(frame.payload)
        except FrameError as exc:
            raise TransportError(f"malformed FAILSAFE_REPLY ({exc}): reflash the bridge "
                                 "firmware (lm629 bridge flash)", port=self.url) from None
        if state.result != Result.OK:
            raise TransportError(f"the bridge refused {what} (result {state.result}): reflash "
                                 "the firmware that matches this host (lm629 bridge flash)",
                                 port=self.url)
        return state

    def _failsafe_open(self) -> None:
        """On open: report a latched trip (a warning) and acknowledge it, as reopening a
        channel does; then arm the failsafe as the URL says (or disarm it)."""
        if not self.has_failsafe:
            return
        with self.lock:
            state = self._failsafe(b"", "FAILSAFE (report)")
            if state.tripped:
                self.failsafe_report = state
                log.warning("%s: %s; acknowledged by this open", self.url, state.describe())
                self._failsafe(bytes((FailsafeCmd.ACKNOWLEDGE,)), "FAILSAFE (acknowledge)")
            self._arm()

    def _arm(self) -> None:
        if not self.failsafe_s:
            self._failsafe(bytes((FailsafeCmd.DISARM,)), "FAILSAFE (disarm)")
            return
        ms = round(self.failsafe_s * 1e3)
        self._failsafe(bytes((FailsafeCmd.ARM,)) + ms.to_bytes(2, "big")
                       + bytes((self.failsafe_action,)), f"FAILSAFE (arm {ms} ms)")
        self.feed_period_s = self.failsafe_s * FEED_FRACTION
        # a far-side wait feeds only when it ends: each one shorter than the timeout
        self.far_wait_limit_s = self.failsafe_s / 2
        if isinstance(self._inner_clock, WallClock):
            if self._feeder is None:
                self._feeder = threading.Thread(target=self._feed_loop, daemon=True,
                                                name=f"lm629 failsafe feeder {self.url}")
                self._feeder.start()
        else:
            self.feed_on_sleep()

    def _feed_if_due(self) -> None:
        """Feed the failsafe when the link has been idle for :attr:`feed_period_s` (any
        exchange feeds it: busy links pay nothing).  A trip seen here is kept in
        :attr:`failsafe_report` and logged once."""
        if not self.feed_period_s or self._closed or self._recording:
            return
        if self.clock.now() - self._last_tx < self.feed_period_s:
            return
        try:
            state = self._failsafe(b"", "FAILSAFE (feed)", retries=1)
        except TransportError as exc:
            log.debug("%s: failsafe feed failed: %s", self.url, exc)
            return
        if state.tripped and self.failsafe_report != state:
            self.failsafe_report = state
            log.warning("%s: %s; acknowledge it (lm629 clear, or clear_failsafe()) before "
                        "moving again", self.url, state.describe())

    def _feed_loop(self) -> None:
        """The feeder thread (wall-clock links): while the process lives, feed whenever the
        link is idle; never waits for the lock (a program under way feeds by itself)."""
        while not self._feeder_stop.wait(self.feed_period_s / 2):
            if self._closed:
                return
            if self._recording:
                self._feed_recording()
                continue
            self.keep_alive(self._feed_if_due, "failsafe feeder")

    def _feed_recording(self) -> None:
        """During a recording: FAILSAFE_FEED, the one frame a recording takes without
        ending, when the link has been quiet for a feed period."""
        if not self.feed_period_s or self.clock.now() - self._last_tx < self.feed_period_s:
            return
        with self._tx_lock:
            if not self._recording:
                return
            self._last_tx = self.clock.now()
            try:
                self.pipe.write(FAILSAFE_FEED)
            except OSError:
                return
            self.stats.bytes_out += len(FAILSAFE_FEED)

    def failsafe_state(self) -> FailsafeState | None:
        """The bridge's failsafe now (armed timeout, action, a latched trip), or None when
        the bridge has no failsafe."""
        if not self.has_failsafe:
            return None
        with self.lock:
            return self._failsafe(b"", "FAILSAFE (report)")

    def clear_failsafe(self) -> FailsafeState | None:
        """Acknowledge a latched trip (the bridge takes trajectory commands again) and arm
        the failsafe again.  Returns the trip acknowledged (the one this open already
        acknowledged, if any), or None when there was none."""
        if not self.has_failsafe:
            return None
        with self.lock:
            state = self._failsafe(b"", "FAILSAFE (report)")
            found = state if state.tripped else self.failsafe_report
            if state.tripped:
                self._failsafe(bytes((FailsafeCmd.ACKNOWLEDGE,)), "FAILSAFE (acknowledge)")
            self.failsafe_report = None
            self._arm()
            return found

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
        if self._closed:
            raise TransportError("the port is closed", port=self.url)
        timeout_us = busy_timeout_us(program)
        self._resync()
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
                ftype, payload, store = self._by_code(payload)
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
            self._forget_codes()
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
            self._codes[store[0]] = store[1]
        # a refused program (BAD_PROGRAM...) is raised by the caller, whatever it carries
        return reply

    def _by_code(self, program: bytes) -> tuple[FrameType, bytes, tuple[bytes, int] | None]:
        """How to send a short program to a bridge that keeps programs under codes: by its
        code (RUN_CODE, 1 byte) when the bridge keeps it; the second time it is seen, with a
        code for it (RUN_STORE: the least recently used code is reused); the first time, as
        it is (RUN_SHORT: programs that carry changing data are not worth a code).  Returns
        the frame type, its payload, and (program, code) to remember once it ran."""
        codes = self._codes
        code = codes.get(program)
        if code is not None:
            codes.move_to_end(program)
            return FrameType.RUN_CODE, bytes((code,)), None
        if program not in self._recent:
            self._recent[program] = None
            if len(self._recent) > 2 * CODE_SLOTS:
                self._recent.popitem(last=False)
            return FrameType.RUN_SHORT, program, None
        used = set(codes.values())
        free = [c for c in range(CODE_SLOTS) if c not in used]
        if free:
            code = free[0]
        else:
            _, code = codes.popitem(last=False)  # the least recently used
        # until it ran, the bridge may hold either program under this code: forget both
        for p, c in list(codes.items()):
            if c == code:
                del codes[p]
        return FrameType.RUN_STORE, bytes((code,)) + program, (program, code)

    def _forget_codes(self) -> None:
        """The bridge forgot its programs (HELLO) or may hold others than we think."""
        self._codes.clear()

    def _account(self, ops: Sequence[BusOp], reply: RunReply) -> None:
        """Bus cycles and busy polls as far as the reply lets us reconstruct them: each busy
        check costs at least one status read (polls beyond the first are not reported)."""
        stats = self.stats
        for o in ops:
            op = o.op
            if op in _BUSY_CHECKED:
                stats.busy_polls += 1
                stats.bus_cycles += 1
            if op is Op.WRITE or op is Op.READ:
                stats.bus_cycles += 2
            elif op is Op.COMMAND or op is Op.STATUS or op is Op.RESET or op is Op.WAIT_STATUS:
                stats.bus_cycles += 1

    def _emit_cycles(self, ops: Sequence[BusOp], words: Sequence[int],
                     statuses: Sequence[int]) -> None:
        if not self._tracing():
            return
        for cycle in cycles_of(ops, ProgramResult(tuple(words), tuple(statuses))):
            self._emit(cycle)

    def _failsafe_tripped(self, nothing: str) -> FailsafeTripped:
        """The error for a request the bridge refused because its failsafe trip is latched
        (FAILSAFE_TRIPPED), with the trip it reports; ``nothing``: what did not happen."""
        try:
            state: FailsafeState | None = self._failsafe(b"", "FAILSAFE (report)")
        except TransportError:
            state = None
        what = state.describe() if state is not None else "the bridge's failsafe tripped"
        return FailsafeTripped(
            f"{what}; {nothing}. The host was silent (suspended, hung?): acknowledge the trip "
            "with `lm629 clear` (Python: clear_failsafe()) before moving again", port=self.url,
            state=state)

    def _raise_result(self, reply: RunReply, ops: list[BusOp], base: int, program: Program,
                      words: list[int]) -> None:
        index = reply.index
        op = ops[index].describe() if index < len(ops) else f"operation {index}"
        where = f" at operation {base + index} ({op})" if index < len(ops) else ""
        if reply.result == Result.FAILSAFE_TRIPPED:
            raise self._failsafe_tripped("nothing of this program ran")
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
        """PROFILE frames (PROFILE_MAX_PIECES pieces each, the first one ``new``): the bridge
        issues each piece on its own timer, its times counted from the first frame's arrival
        (so the link's latency shifts them all alike and jitters none).  A schedule the bridge
        refuses is a :class:`TransportError` naming why."""
        if not self.far_profiles:
            return super().profile(axis, pieces, new=new)
        cs = self.cs if axis is None else axis
        times = [(round(t * 1e6), v) for t, v in pieces]
        chunks = [times[k:k + PROFILE_MAX_PIECES]
                  for k in range(0, len(times), PROFILE_MAX_PIECES)] or [[]]
        state = ProfileState(0, 0, 0.0)
        for k, chunk in enumerate(chunks):
            payload = profile_payload(new and k == 0, cs, chunk)
            frame = self._exchange(FrameType.PROFILE, payload,
                                   self.reply_timeout(wire_size(len(payload) + 4),
                                                      wire_size(PROFILE_REPLY_PAYLOAD.size + 4)),
                                   f"PROFILE of {len(chunk)} piece(s)", self.retries)
            if len(frame.payload) != PROFILE_REPLY_PAYLOAD.size:
                raise TransportError("the bridge's PROFILE_REPLY has the wrong length: reflash "
                                     "the firmware that matches this host", port=self.url)
            result, issued, pending, late_us = PROFILE_REPLY_PAYLOAD.unpack(frame.payload)
            if result == Result.FAILSAFE_TRIPPED:
                raise self._failsafe_tripped("nothing of the shaped move was scheduled")
            if result == Result.BAD_PROFILE:
                raise TransportError(
                    f"the bridge refused the shaped move's pieces (BAD_PROFILE): pieces out of "
                    f"order or closer than 10 ms, a velocity above 3FFFFFFF, chip select {cs} "
                    "or more pieces than it holds; nothing was scheduled", port=self.url)
            state = ProfileState(issued, pending, late_us * 1e-6,
                                 result == Result.PROFILE_CANCELLED)
        return state

    # ------------------------------------------------------------------ recording (RECORD)
    @property
    def records_on_far_side(self) -> bool:
        """Only with RECORD: without it every row is a host exchange, stamped when it starts
        (in simulated time too)."""
        return self.has_record

    def record_note(self) -> str:
        if self.has_record:
            return ("rows sampled by the bridge on its own timer and stamped with its clock "
                    f"({RECORD_TICK_US} us ticks): the link's latency changes only when they "
                    "arrive")
        return super().record_note()

    #: the bridge's bus time for a sample program, per data-reporting command (busy check,
    #: strobe, the chip busy with it) and per byte read: a generous estimate for the rate check
    RECORD_US_PER_COMMAND = 25.0
    RECORD_US_PER_READ = 4.0

    def record_max_rate(self, program: Program) -> float | None:
        """Rows per second the line carries for ``program``: the bridge sends each row before
        it samples the next, so a row costs its bus time plus its wire time (at 11 bits a byte,
        what a two-stop-bit UART or simavr takes), with 10 % to spare."""
        if not self.has_record:
            return super().record_max_rate(program)
        _, read = self._check_sample(program)
        n_cmd = sum(1 for o in program.ops if o.op is Op.COMMAND)
        n_read = sum(1 for o in program.ops if o.op in (Op.READ, Op.STATUS))
        bus_s = (n_cmd * self.RECORD_US_PER_COMMAND + n_read * self.RECORD_US_PER_READ) * 1e-6
        wire_s = row_wire_bytes(read) * 11 / self.baud if self.baud else 0.0
        return min(0.9 / (bus_s + wire_s), 1e6 / RECORD_MIN_PERIOD_US)

    def _check_sample(self, program: Program) -> tuple[int, int]:
        try:
            return check_record_program(program.ops, self.chip_selects)
        except BadProgram as exc:
            raise ValueError(f"not a sample program: {exc}") from None

    def record_rows(self, program: Program, period_s: float, rows: int) -> Iterator[RawRow]:
        """RECORD: the bridge runs ``program`` every ``period_s`` on its own timer and streams
        the rows, each stamped with its clock; the host only reads them.  One exchange (a
        request no row answers within its time is sent again, with a new ``seq``: the program
        only reads, so a recording started twice changes nothing on the chip).  A row lost on
        the line is missing from what is yielded (its index is the gap).  Closing the iterator
        early stops the bridge (any byte from the host ends a recording)."""
        if not self.has_record:
            yield from super().record_rows(program, period_s, rows)
            return
        if self._closed:
            raise TransportError("the port is closed", port=self.url)
        _, read = self._check_sample(program)
        ticks = max(1, round(period_s * 1e6 / RECORD_TICK_US))
        period_us = ticks * RECORD_TICK_US
        if period_us < RECORD_MIN_PERIOD_US or not 0 <= rows <= 0xFFFF:
            raise ValueError(f"period {period_s * 1e6:g} us / {rows} rows: the bridge records "
                             f"every {RECORD_MIN_PERIOD_US} us or slower, up to 65535 rows")
        period = period_us * 1e-6
        ops = program.ops
        payload = record_payload(period_us, rows, ops)
        row_wire = row_wire_bytes(read)
        clock = self.clock
        stats = self.stats
        with self.lock:
            self._resync()
            stats.programs += 1
            pending: deque[Frame] = deque()
            first = self._exchange(
                FrameType.RECORD, payload,
                period + self.reply_timeout(wire_size(len(payload) + 4), row_wire, ops,
                                            FIRMWARE_DEFAULT_BUSY_TIMEOUT_US * 1e-6),
                "RECORD", self.retries, pending=pending)
            seq = first.seq
            ended = False
            self._recording = True  # from now on the feeds are FAILSAFE_FEED
            try:
                last_index = -1
                last_us = None
                t_us = 0
                silence = max(0.25, 20 * period) + self.margin_s
                end_at = clock.now() + rows * period if rows else None
                frame: Frame | None = first
                while True:
                    if frame is None:
                        if end_at is None:
                            raise LinkError(f"no row from the bridge for {silence:g} s during "
                                            f"a recording: {self._quality()}", port=self.url,
                                            may_have_run=True)
                        return  # the last rows (and the end) were lost: they are gaps
                    if frame.type == FrameType.RECORD_END:
                        ended = True
                        self._end_of_recording(frame, ops)
                        return
                    if frame.type == FrameType.RECORD_ROW:
                        row = self._decode_row(frame.payload, ops)
                        if row is not None:
                            idx16, stamp, words, statuses = row
                            index = last_index + ((idx16 - last_index) & 0xFFFF) \
                                if last_index >= 0 else idx16
                            t_us = stamp if last_us is None else t_us + ((stamp - last_us) & 0xFFFFFFFF)
                            last_index, last_us = index, stamp
                            self._account(ops, RunReply())  # the row's bus cycles, as a RUN's
                            self._emit_cycles(ops, words, statuses)
                            yield RawRow(index, t_us * 1e-6, words, statuses)
                            if rows and index >= rows - 1:
                                # the end follows at once: take it, or leave it to be ignored
                                nxt = self._next_frame(seq, clock.now() + self.reply_timeout(
                                    wire_size(9), wire_size(9)), pending)
                                ended = nxt is not None and nxt.type == FrameType.RECORD_END
                                if ended:
                                    self._end_of_recording(cast(Frame, nxt), ops)
                                return
                    else:
                        self.stale_replies += 1
                    wait = silence
                    if end_at is not None:
                        wait = max(wait, end_at - clock.now() + silence)
                    frame = self._next_frame(seq, clock.now() + wait, pending)
            finally:
                with self._tx_lock:
                    self._recording = False
                if not ended:
                    self._stop_recording(seq, pending, period)

    def _next_frame(self, seq: int, deadline: float, pending: deque[Frame]) -> Frame | None:
        """The next frame of the recording ``seq``, or None at ``deadline``.  A bad frame
        does not end the wait: it was a row, and a lost row is a gap.  With the failsafe armed
        the host feeds it while it waits (a recording counts as alive only while it sends)."""
        return self._await(seq, deadline, pending, bad_ends_wait=False,
                           feed=bool(self._recording and self.feed_period_s))

    def _decode_row(self, payload: bytes, ops: Sequence[BusOp]
                    ) -> tuple[int, int, tuple[int, ...], tuple[int, ...]] | None:
        """(row, t_us, words, statuses) of a RECORD_ROW, or None for one that passed its CRC
        but does not hold what ``ops`` read (line damage: a gap, counted as a bad frame)."""
        n = ROW_HEADER.size
        if len(payload) < n:
            self.bad_frames += 1
            return None
        idx16, stamp = ROW_HEADER.unpack_from(payload)
        try:
            r = decode_short_reply(payload[n:] + b"\x00", ops)
        except FrameError:
            self.bad_frames += 1
            return None
        return idx16, stamp, r.words, r.statuses

    def _end_of_recording(self, frame: Frame, ops: Sequence[BusOp]) -> None:
        """RECORD_END: OK, or the error that stopped (or refused) the recording."""
        if len(frame.payload) != END_PAYLOAD.size:
            return  # damaged past its CRC: the rows already say what was recorded
        result, index, sent = END_PAYLOAD.unpack(frame.payload)
        if result == Result.OK:
            return
        if result == Result.BUSY_TIMEOUT and index < len(ops):
            raise BusyTimeout(ops[index].describe(), FIRMWARE_DEFAULT_BUSY_TIMEOUT_US * 1e-6,
                              NONE_BYTE, index, [])
        try:
            name = Result(result).name
        except ValueError:
            name = f"unknown result {result}"
        raise LinkError(f"the bridge refused the recording ({name}, after {sent} row(s)): host "
                        "and firmware disagree on RECORD; reflash the firmware that matches "
                        "this host (lm629 bridge flash)", port=self.url, may_have_run=False)

    def _stop_recording(self, seq: int, pending: deque[Frame], period: float) -> None:
        """End a recording early: one byte stops the bridge; its RECORD_END (or a row already
        on its way) is read and dropped, so that the next request starts on a quiet line."""
        try:
            with self._tx_lock:
                self.pipe.write(b"\x00")
            self.stats.bytes_out += 1
            deadline = self.clock.now() + 2 * period + self.reply_timeout(
                wire_size(64), wire_size(64))
            while True:
                f = self._next_frame(seq, deadline, pending)
                if f is None or f.type == FrameType.RECORD_END:
                    return
        except (OSError, TransportError):  # the port went away: nothing left to stop
            return

    # ------------------------------------------------------------------ misc
    def describe(self) -> str:
        if self.info is None:
            return self.url
        return f"{self.url} ({self.info.describe()})"

    def close(self) -> None:
        """Disarm the failsafe (a clean close: an axis left moving on purpose keeps moving),
        then release the port."""
        if not self._closed:
            self._feeder_stop.set()
            if self.feed_period_s:
                try:
                    with self.lock:
                        self._failsafe(bytes((FailsafeCmd.DISARM,)), "FAILSAFE (disarm)",
                                       retries=1)
                except (TransportError, OSError) as exc:
                    log.debug("%s: failsafe not disarmed: %s", self.url, exc)
                self.feed_period_s = 0.0
            self._closed = True
            self.pipe.close()


__all__ = ["BAD_LINK_RATE", "DEFAULT_RETRIES", "ERROR_WINDOW", "FAILSAFE_OPTIONS",
           "FAILSAFE_OPTION_NAMES", "FailsafeTripped", "LinkError", "LinkTransport", "Pipe",
           "failsafe_options",
           "WARN_LINK_RATE"]
