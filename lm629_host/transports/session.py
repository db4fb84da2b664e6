"""The session core of the link to a bridge: framing, one request and its answer, retries with
the same ``seq``, resynchronisation after a give-up, and the line's measured error rate.

:class:`LinkSession` knows frames, not bus programs: :class:`~lm629_host.transports.link.LinkTransport`
builds on it, and each of the link's other jobs (the failsafe, the recorder, the PROFILE
scheduler, the program-code cache, the baud switch) is its own module that sends through it.
"""

from __future__ import annotations

import logging
import random
import threading
from collections import deque
from collections.abc import Callable, Sequence

from lm629_host.bridge.protocol.constants import ALSO_REPLY_TO, REPLY_TO, RUN_TYPES, FrameType, MAX_PING
from lm629_host.bridge.protocol.framing import Frame, FrameError, FrameReader, encode_frame, wire_size
from lm629_host.bridge.protocol.hello import HelloInfo
from lm629_host.bridge.protocol.pipe import Pipe
from lm629_host.bridge.protocol.run import RunReply
from lm629_host.bus.program import BusOp, Op, ProgramResult, TraceCallback, cycles_of
from lm629_host.errors import LinkError, TransportError
from lm629_host.urls import PortURL
from lm629_host.transports.base import Transport

#: the answers to the protocol's requests: one with the awaited seq but answering another kind
#: of request is stale, not a firmware that speaks another protocol (a client killed in a
#: long WAIT_STATUS leaves its RUN_REPLY to come when the next client's first byte ends the
#: wait; the next client's HELLO may have drawn the same seq); ERROR_REPLY is an answer to all
_OTHER_ANSWERS = frozenset(REPLY_TO.values()) | frozenset(ALSO_REPLY_TO.values())

log = logging.getLogger("lm629_host.bridge.protocol")

#: retries of one request (same ``seq``, same bytes) before the host gives up.  Seven: at 1 % of
#: bytes faulty (each of drop, corrupt, duplicate, delay at 0.25 %) one attempt of a small RUN
#: fails about one time in five, so 3 retries leave ~0.15 % of commands failed, 7 leave none
#: measured in 100,000 (docs/bridge.md); a dead link costs 8 timeouts to notice
DEFAULT_RETRIES = 7
#: how many recent attempts :attr:`LinkSession.error_rate` looks back over
ERROR_WINDOW = 200
#: an error rate above this makes a give-up message call the link too bad to use
BAD_LINK_RATE = 0.2
#: above this error rate (over a full window) the link logs one warning per window, even while
#: the retries still hide every failure: 5 % of exchanges failing is a cable to look at
WARN_LINK_RATE = 0.05

_BUSY_CHECKED = (Op.COMMAND, Op.WRITE, Op.READ, Op.SYNC)
#: the ``seq`` no request of the host carries: FAILSAFE_FEED's, so that the bridge's answer to a
#: feed (a FAILSAFE_REPLY with seq 0) can never be taken for the answer to a request
FEED_SEQ = 0
#: a read that returns this much later than asked (seconds, and at least as late again as the
#: wait it was asked for) means the host itself stalled: suspended, paused, starved of CPU
HOST_STALL_S = 0.1
#: what to check when the line fails, for a pipe that does not say what it is (``line_advice``)
USB_ADVICE = ("Check the USB cable (short, shielded, away from motor and amplifier wiring), "
              "the ground between the bridge and the LM629 board")

#: requests sent after a lone delimiter from their first attempt on (a retry always is): the
#: first contact, when the far end may hold half a frame of whoever had the port before, and
#: RECORD, which starts where a recording may still be streaming (a byte ends it)
_DELIMITED = frozenset({FrameType.HELLO, FrameType.RECORD})


class AttemptWindow:
    """The last :data:`ERROR_WINDOW` attempts of a link, True for each that failed (a bad
    frame, or no usable answer in time): the line's health as the host sees it, and when it
    is bad enough to say so (once a window, before it costs a command)."""

    def __init__(self) -> None:
        self._attempts: deque[bool] = deque(maxlen=ERROR_WINDOW)
        self._since_warning = 0  #: attempts since the last link-quality warning

    @property
    def rate(self) -> float:
        """Fraction of the attempts in the window that failed."""
        a = self._attempts
        return sum(a) / len(a) if a else 0.0

    @property
    def failed(self) -> int:
        return sum(self._attempts)

    def __len__(self) -> int:
        return len(self._attempts)

    def count(self, failed: bool) -> bool:
        """Count one attempt; True when the line is bad enough to warn (once per window)."""
        self._attempts.append(failed)
        self._since_warning += 1
        if (self._since_warning >= ERROR_WINDOW and len(self._attempts) == ERROR_WINDOW
                and self.rate >= WARN_LINK_RATE):
            self._since_warning = 0
            return True
        return False

    def clear(self) -> None:
        """Forget the attempts (a new open: the line may be another)."""
        self._attempts.clear()


class LinkSession(Transport):
    """Requests and answers over a :class:`Pipe` to a bridge speaking PROTOCOL.md.

    The reply timeout is computed per request (:meth:`reply_timeout`).  On a timeout or a bad
    frame the same frame is sent again, ``retries`` times at most; replies with another ``seq``
    (late answers to earlier attempts) are ignored.
    """

    #: added to every reply timeout: the far end's own processing time and the latency of a
    #: USB serial adapter (a simulated pipe may lower it: its latency is known)
    margin_s: float = 0.05
    #: bits on the wire per byte for the timeout estimate: start + 8 data + stop (a simulated
    #: UART with two stop bits sets 11)
    wire_bits: int = 10
    #: the wait for one HELLO_REPLY before HELLO is sent again
    hello_interval_s: float = 0.1

    def __init__(self, pipe: Pipe, url: str | PortURL, *, trace: TraceCallback | None = None,
                 retries: int = DEFAULT_RETRIES, baud: int | None = None) -> None:
        super().__init__(url, trace=trace)
        if retries < 0:
            raise ValueError(f"retries={retries} must be >= 0")
        if baud is not None and baud <= 0:
            raise ValueError(f"baud={baud} must be a positive number of bits per second")
        self.pipe = pipe
        self.clock = pipe.clock
        self.retries = retries
        self.baud = baud
        self._seq = random.randrange(256)
        self._reader = FrameReader()
        self._closed = False
        #: bad frames and stale replies seen (for the fault tests and ``doctor``)
        self.bad_frames = 0
        self.stale_replies = 0
        self.timeouts = 0  #: attempts that got no (usable) answer in time
        self.attempts = AttemptWindow()  #: the last ERROR_WINDOW attempts (:attr:`error_rate`)
        #: a request was given up: the bridge's cache may still hold its seq, so the next
        #: request is preceded by a HELLO (which empties that cache) -- see :meth:`resync`
        self._need_resync = False
        self._last_tx = self.clock.now()
        #: the pipe's two directions: ``_tx_lock`` around each write (a frame is never cut by
        #: another thread's), ``_rx_lock`` around a request and its answer (whoever holds it
        #: reads); neither is the user-visible :attr:`lock`, so that a keep-alive can send
        #: between programs while a user thread holds that one around a sequence
        self._tx_lock = threading.Lock()
        self._rx_lock = threading.RLock()
        #: frames the host did not ask for, by type, to their owner (the failsafe's reports)
        self._events: dict[int, Callable[[Frame], None]] = {}
        #: the longest the host was seen to stall in a read since the last request that got
        #: its answer (0: none): a timeout after a stall is the host's, not the line's
        self.host_late_s = 0.0
        self.info: HelloInfo | None = None  #: the bridge's HELLO_REPLY, once answered

    def _bridge_forgot(self) -> None:
        """Hook: a HELLO was answered, so the bridge emptied its reply cache and its program
        codes (the transport forgets the codes it thinks the bridge keeps)."""

    # ------------------------------------------------------------------ helpers
    def _next_seq(self) -> int:
        self._seq = (self._seq + 1) & 0xFF
        if self._seq == FEED_SEQ:  # the feed's, never a request's
            self._seq = FEED_SEQ + 1
        return self._seq

    # ------------------------------------------------------------------ the parts' interface
    # What the link's parts (failsafe, recorder, PROFILE scheduler, baud switch) use: a
    # request with its retries and check, events, the idle time, a raw send, invalidation.
    def request(self, ftype: FrameType, payload: bytes, what: str, reply_wire: int, *,
                ops: Sequence[BusOp] = (), busy_timeout_s: float = 0.0, extra_s: float = 0.0,
                retries: int | None = None, check: Callable[[Frame], object] | None = None,
                pending: deque[Frame] | None = None, resync: bool = True,
                timeout_s: float | None = None) -> Frame:
        """One request and its answer: a HELLO first when an earlier request was given up
        (:meth:`resync`; ``resync=False``: not, for the HELLO that checks a new baud rate),
        then ``ftype`` with ``payload`` until answered, ``retries`` times at most (None: the
        link's).  The reply timeout is :meth:`reply_timeout` of the request and
        ``reply_wire`` (the answer's size on the wire) with ``ops`` and ``busy_timeout_s``,
        plus ``extra_s`` (a recording's first period); ``timeout_s`` replaces all that (a
        HELLO's own wait).  ``check`` and ``pending``: as :meth:`_exchange` says."""
        if resync:
            self.resync()
        timeout = timeout_s if timeout_s is not None else extra_s + self.reply_timeout(
            wire_size(len(payload) + 4), reply_wire, ops, busy_timeout_s)
        return self._exchange(ftype, payload, timeout, what,
                              self.retries if retries is None else retries, check, pending)

    def on_event(self, ftype: FrameType, handler: Callable[[Frame], None]) -> None:
        """Hand every ``ftype`` frame the host did not ask for to ``handler`` (the failsafe's
        reports and the answers to its feeds)."""
        self._events[ftype] = handler

    @property
    def last_sent(self) -> float:
        """When the host last wrote to the bridge, on the link's clock: every frame feeds the
        bridge's failsafe, so this is when the bridge last heard the host."""
        return self._last_tx

    def idle_s(self) -> float:
        """How long the host has written nothing to the bridge (on the link's clock)."""
        return self.clock.now() - self._last_tx

    def send_unsolicited(self, wire: bytes, when: Callable[[], bool] | None = None, *,
                         feeds: bool = True) -> bool:
        """Write a frame that asks no answer (FAILSAFE_FEED, the byte that ends a recording)
        whole, between other writes; with ``when``, only if it still says so once no other
        write is under way.  ``feeds``: it is a whole frame, so the bridge heard the host
        (:attr:`last_sent`; a lone delimiter is none).  True when it was written."""
        with self._tx_lock:
            if when is not None and not when():
                return False
            before = self._last_tx
            if feeds:
                self._last_tx = self.clock.now()
            try:
                self.pipe.write(wire)
            except BaseException:
                self._last_tx = before  # a write that failed fed nothing
                raise
        self.stats.bytes_out += len(wire)
        return True

    @property
    def request_lock(self) -> threading.RLock:
        """Held around a request and its answer (whoever holds it reads the pipe); not the
        user-visible :attr:`lock`: a keep-alive takes it (without waiting) between programs
        while a user thread holds that one around a sequence."""
        return self._rx_lock

    @property
    def write_lock(self) -> threading.Lock:
        """Held around each write, so that no frame is cut by another thread's."""
        return self._tx_lock

    def invalidate(self) -> None:
        """The bridge may hold a stale answer in its cache (a request was given up, a baud
        switch failed): the next request is preceded by a HELLO (:meth:`resync`)."""
        self._need_resync = True

    def count_cycles(self, ops: Sequence[BusOp], words: Sequence[int],
                     statuses: Sequence[int]) -> None:
        """Count and trace the bus cycles of ``ops`` run on the far side (a recording's row,
        as a RUN's)."""
        self._account(ops, RunReply())
        self._emit_cycles(ops, words, statuses)

    def poll_events(self) -> None:
        """Read what is already waiting on the pipe (without waiting) and hand each frame the
        host did not ask for to its owner; the caller holds ``_rx_lock`` (no request is
        waiting for an answer)."""
        data = self.pipe.read(0.0)
        if not data:
            return
        self.stats.bytes_in += len(data)
        for item in self._reader.feed(data):
            if isinstance(item, FrameError):
                self.bad_frames += 1
            else:
                self._dispatch(item, None)

    def _dispatch(self, frame: Frame, seq: int | None) -> None:
        """A frame that is not the answer awaited: to its owner by type, else counted stale."""
        owner = self._events.get(frame.type)
        if owner is not None:
            owner(frame)
            return
        self.stale_replies += 1
        log.debug("%s: ignored frame type %02X seq %d (waiting for %s)", self.url, frame.type,
                  frame.seq, seq)

    def line_advice(self) -> str:
        """What to check when the line fails: the pipe says what it is (``line_advice``: a
        pseudo-terminal, a socket); else it is taken for a USB serial adapter's cable (the
        simulated lines model one)."""
        advice = getattr(self.pipe, "line_advice", None)
        return advice if isinstance(advice, str) else USB_ADVICE

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
        return self.attempts.rate

    def _attempt(self, failed: bool) -> None:
        """Count one attempt; warn (once per window) when the line is bad, before it costs a
        command."""
        if self.attempts.count(failed):
            log.warning("%s: %s", self.url, self.quality())

    def quality(self) -> str:
        """One sentence on the measured link quality and what to check."""
        failed, n, rate = self.attempts.failed, len(self.attempts), self.attempts.rate
        verdict = ("the link is too noisy to use: " if rate >= BAD_LINK_RATE
                   else "link quality: ")
        return (f"{verdict}{failed} of the last {n} exchanges failed ({100 * rate:.0f} %; "
                f"{self.bad_frames} bad frame(s), {self.timeouts} timeout(s) since open). "
                f"{self.line_advice()}, and that the baud rate matches the firmware's "
                f"({self.baud or '?'} here)")

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
        with self._rx_lock:
            return self._exchange_locked(ftype, payload, timeout_s, what, retries, check,
                                         pending)

    def _exchange_locked(self, ftype: FrameType, payload: bytes, timeout_s: float, what: str,
                         retries: int, check: Callable[[Frame], object] | None,
                         pending: deque[Frame] | None) -> Frame:
        fresh = ftype is FrameType.RECORD
        seq = self._next_seq()
        wire = encode_frame(ftype, seq, payload)
        want = REPLY_TO[ftype]
        also = ALSO_REPLY_TO.get(ftype)
        accept = (want,) if also is None else (want, also)
        stats = self.stats
        clock = self.clock
        attempts = 0
        bad_before = self.bad_frames
        self.host_late_s = 0.0
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
            with self._tx_lock:
                self._last_tx = clock.now()
                self.pipe.write(out)
            stats.bytes_out += len(out)
            stats.round_trips += 1
            deadline = clock.now() + timeout_s
            if pending is not None:
                pending.clear()
            frame = self.await_reply(seq, deadline, pending, accept=accept)
            if frame is None:
                self._attempt(True)
                continue
            if frame.type == FrameType.ERROR_REPLY:
                code = frame.payload[0] if frame.payload else -1
                raise TransportError(
                    f"the bridge refused {what} (ERROR_REPLY, code {code}): the host and the "
                    "firmware disagree on the protocol. Reflash the firmware that matches this "
                    "host (lm629 bridge flash).", port=self.url)
            if frame.type not in accept:
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
            if ftype is FrameType.HELLO:
                self._bridge_forgot()  # HELLO empties the bridge's codes and cache
            return frame
        late = self.host_late_s
        if ftype is not FrameType.HELLO:
            self._need_resync = True  # the bridge may hold this seq in its cache
        if late:
            # the host's own clock jumped while it waited: its timeouts are not the line's
            raise LinkError(
                f"no answer to {what} after {attempts} attempt(s), but this host was late: it "
                f"stalled for {late:.2f} s while it waited (paused, suspended or starved of "
                "CPU), so the answers may have come and gone; "
                + ("the program may or may not have run on the chip; reset the chip "
                   "(LM629.reset) before going on" if ftype in RUN_TYPES else
                   "nothing is wrong with the line as far as the host can tell"),
                port=self.url, may_have_run=ftype is not FrameType.HELLO, host_late_s=late)
        if ftype is FrameType.HELLO:
            raise self._no_answer(what, attempts)
        if fresh:  # the bridge answered HELLO: the line, not the firmware, is the suspect
            raise LinkError(f"no answer to {what} after {attempts} attempt(s): "
                            f"{self.quality()}", port=self.url, may_have_run=True)
        if ftype not in RUN_TYPES:
            raise self._no_answer(what, attempts)
        raise LinkError(
            f"no valid answer to {what} after {attempts} attempt(s) "
            f"({self.bad_frames - bad_before} bad frame(s)): the program may or may not "
            f"have run on the chip; {self.quality()}; then reset the chip (LM629.reset) "
            "before going on.", port=self.url, may_have_run=True)

    def await_reply(self, seq: int, deadline: float, pending: deque[Frame] | None = None, *,
                    bad_ends_wait: bool = True, tick: Callable[[], None] | None = None,
                    every: float = 0.0, accept: tuple[int, ...] | None = None) -> Frame | None:
        """The next reply with ``seq``, or None at ``deadline`` (a timeout) or, with
        ``bad_ends_wait``, on a bad frame: the far end does not answer a request it could not
        read, so a request calls for a retry at once.  A recording's rows come several in one
        read: the ones after the first wait in ``pending`` (taken first by the next call);
        without ``pending`` a request has one reply and the rest are dropped.  With ``tick``
        (a recording's keep-alive) the wait is read in steps of ``every`` seconds, each begun
        with ``tick()``.

        The answer is a frame with ``seq`` (and of a type in ``accept``, when given); a frame
        the host did not ask for (a failsafe report, a late row) goes to its owner by type
        (:meth:`_dispatch`), never taken for the answer.  A read that returns much later than
        asked is the host's own stall, kept in :attr:`host_late_s`."""
        with self._rx_lock:
            return self._await_locked(seq, deadline, pending, bad_ends_wait, tick, every,
                                      accept)

    def _await_locked(self, seq: int, deadline: float, pending: deque[Frame] | None,
                      bad_ends_wait: bool, tick: Callable[[], None] | None, every: float,
                      accept: tuple[int, ...] | None) -> Frame | None:
        if pending:
            return pending.popleft()
        queue: deque[Frame] = pending if pending is not None else deque()
        clock = self.clock
        while True:
            if tick is not None:
                tick()
            left = deadline - clock.now()
            if left <= 0:
                self.timeouts += 1
                return None
            asked = min(left, every) if tick is not None else left
            t0 = clock.now()
            data = self.pipe.read(asked)
            late = clock.now() - t0 - asked
            if late > HOST_STALL_S and late > asked:
                self.host_late_s = max(self.host_late_s, late + asked)
            if not data:
                if tick is not None and clock.now() < deadline:
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
                elif (item.seq == seq and item.type & 0x80
                      and (accept is None or item.type in accept
                           or item.type not in self._events
                           and item.type not in _OTHER_ANSWERS)):
                    queue.append(item)  # the answer (or a wrong one: the caller says so)
                else:
                    self._dispatch(item, seq)
            if queue:
                return queue.popleft()
            if bad and bad_ends_wait:
                return None

    def resync(self) -> None:
        """After a request was given up, HELLO before the next one.

        The bridge answers a RUN whose seq and CRC equal its cached ones from the cache.  The
        seq wraps at 256, so after a give-up (the bridge may hold that request's reply) a
        later request with the same bytes could come round to the same seq while nothing in
        between reached the bridge (a cable out for 256 calls of a polling loop): it would be
        answered from the cache and never run.  HELLO empties the cache; until a HELLO is
        answered, no request is sent at all (so those failures are certain: nothing ran)."""
        if not self._need_resync:
            return
        try:
            self.request(FrameType.HELLO, b"", "HELLO (resynchronising after a failed "
                         "exchange)", wire_size(4 + HelloInfo.SIZE), resync=False,
                         timeout_s=max(self.hello_interval_s, self.reply_timeout(
                             wire_size(4), wire_size(4 + HelloInfo.SIZE))))
        except TransportError:
            raise LinkError(
                "no answer from the bridge since the last failed exchange (HELLO unanswered "
                f"{self.retries + 1} times): nothing was sent to the chip; {self.quality()}.",
                port=self.url, may_have_run=False) from None
        self._need_resync = False

    # ------------------------------------------------------------------ accounting
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

    # ------------------------------------------------------------------ requests every bridge takes
    def ping(self, data: bytes = b"") -> float:
        """PING with ``data`` echoed; returns the round-trip time on the pipe's clock."""
        if len(data) > MAX_PING:
            raise ValueError(f"ping payload of {len(data)} bytes is longer than {MAX_PING}")
        self.resync()
        t0 = self.clock.now()
        frame = self.request(FrameType.PING, data, "PING", wire_size(4 + len(data)),
                             resync=False)
        if frame.payload != data:
            raise TransportError("PONG does not echo the PING payload: the link corrupts data "
                                 "that passes its CRC; check the baud rate", port=self.url)
        return self.clock.now() - t0


__all__ = ["AttemptWindow", "BAD_LINK_RATE", "DEFAULT_RETRIES", "ERROR_WINDOW", "LinkSession", "WARN_LINK_RATE"]
