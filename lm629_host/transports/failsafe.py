"""The link's failsafe, the host's half: arm it at open, feed it, hear and tell a trip, and
acknowledge it (PROTOCOL.md, FAILSAFE).  The bridge keeps the timer and stops the chips; this
module only talks to it through the link's session.

Feeding: every good frame feeds the bridge, so a host that talks pays nothing.  A quiet host
sends FAILSAFE_FEED (seq 0, no answer awaited: its FAILSAFE_REPLY is an event, read whenever
the host next reads) once the link has been quiet for a quarter of the timeout.  Who sends it
is the URL's ``failsafe_feed``:

* ``process`` (the default): a :class:`~lm629_host.transports.keepalive.KeepAlive`, a thread
  on the wall clock (the steps of every sleep on a simulated one), while the process lives:
  it needs neither the user-visible program lock nor the main thread, so a script that holds
  ``transport.lock`` around a sequence, computes, or sits in a long recording stays fed.
  A dead, killed or paused process stops the axes.
* ``script``: nothing in the background; only the script's own commands and an explicit
  ``transport.feed()`` feed the bridge, so a script stuck in a loop stops the axes too (the
  Phidget22/ODrive practice).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, NamedTuple

from lm629_host.bridge.protocol import (
    FAILSAFE_FEED,
    FAILSAFE_MAX_MS,
    FAILSAFE_MIN_MS,
    FailsafeAction,
    FailsafeCmd,
    FailsafeState,
    Frame,
    FrameError,
    FrameType,
    Result,
    encode_frame,
    wire_size,
)
from lm629_host.errors import FailsafeTripped, TransportError
from lm629_host.transports.keepalive import KeepAlive, on_wall_clock
from lm629_host.urls import Option, PortURL, read_rows

if TYPE_CHECKING:
    from lm629_host.transports.session import LinkSession

log = logging.getLogger("lm629_host.bridge.protocol")

#: the failsafe's URL options, taken by every bridge port (``failsafe=0``: disarmed)
FAILSAFE_DEFAULT_S = 0.5
FEED_MODES = ("process", "script")
FAILSAFE_OPTIONS = (
    Option("failsafe", "float", FAILSAFE_DEFAULT_S, FAILSAFE_MIN_MS / 1e3, FAILSAFE_MAX_MS / 1e3,
           "s", off=0),
    Option("failsafe_action", "str", "abrupt", choices=tuple(a.name.lower() for a in FailsafeAction)),
    Option("failsafe_feed", "str", FEED_MODES[0], choices=FEED_MODES))
#: the feeder sends when the link has been idle this fraction of the failsafe's timeout: three
#: feeds may be lost on the line, or the feeder be that late, before the bridge trips
FEED_FRACTION = 0.25
#: the same on a simulated clock, where the host is never late (it sleeps exactly to the due
#: time: :class:`~lm629_host.transports.keepalive.FeedingClock`) and a feed is the dearest thing
#: an idle simulation does (simavr runs the AVR's UART a cycle at a time): a quarter of the
#: timeout is left for the feed's bytes (a few ms, behind a simulated Uno's USB too)
SIMULATED_FEED_FRACTION = 0.75
#: the feed of a quiet link on a simulated clock: PING with the feed's seq (0) and no payload.
#: Its PONG is 7 bytes against FAILSAFE_REPLY's 18, and the far end's reply is what an idle
#: simulation pays for (simavr runs the AVR's UART a cycle at a time: 3x the idle speed).  It
#: carries no trip report: in simulated time the host is never late, so a trip is heard as
#: everywhere else, before the first program after a silence (:meth:`LinkFailsafe.check`)
#: and from a refused STT.  A recording is always fed with FAILSAFE_FEED (the one frame it
#: takes without ending).
SIMULATED_FEED = encode_frame(FrameType.PING, 0)
#: a trip the keep-alive heard goes to the log when no program has raised it this long after
#: (a host busy in its own code); a host that calls the chip is told once, by the error
UNTOLD_LOG_S = 1.0


class FailsafeOptions(NamedTuple):
    """A bridge port's failsafe options, settled from its URL."""

    seconds: float  #: the timeout (0: disarmed)
    action: FailsafeAction  #: how the bridge stops the chips
    feed: str  #: who feeds: ``process`` or ``script``

    @classmethod
    def of(cls, values: dict[str, Any]) -> FailsafeOptions:
        """From a port's parsed options (its table holds :data:`FAILSAFE_OPTIONS`)."""
        return cls(values["failsafe"], FailsafeAction[values["failsafe_action"].upper()],
                   values["failsafe_feed"])


def failsafe_options(url: str | PortURL) -> FailsafeOptions:
    """``failsafe=SECONDS`` (0: off, else 0.05..10), ``failsafe_action=abrupt|smooth|off`` and
    ``failsafe_feed=process|script`` of a bridge port's URL; ValueError naming the option (the
    other options are not looked at)."""
    return FailsafeOptions.of(read_rows(url, FAILSAFE_OPTIONS))


class LinkFailsafe:
    """The failsafe of one link: what the URL asked for, whether the bridge has one, the trips
    heard, and the keep-alive."""

    def __init__(self, link: LinkSession, options: FailsafeOptions | None = None) -> None:
        self.link = link
        # the port parsed them with its other options (None: a link made by hand)
        opts = options if options is not None else failsafe_options(link.port_url)
        #: the failsafe asked for by the URL (seconds, 0: off), its action, who feeds it
        self.timeout_s, self.action, self.feed_mode = opts
        self.available = False  #: the bridge has one (HELLO's capability bit 9)
        #: the trip this open found latched (and acknowledged), or the last one heard since
        self.report: FailsafeState | None = None
        #: a trip heard and not told yet: the next program raises it (once)
        self.news: FailsafeState | None = None
        #: when :attr:`news` was heard (link clock), and whether it went to the log already
        self._news_at = 0.0
        self._news_logged = False
        #: a quiet link is fed after this long (0: the failsafe is not armed)
        self.feed_period_s = 0.0
        self.keepalive: KeepAlive | None = None
        #: set while a recording streams: a feed then goes out whatever reads the pipe
        self.recording = False
        #: called at each turn of the keep-alive before it feeds (the link's PROFILE top-ups)
        self.on_turn: Callable[[], None] | None = None
        #: what a quiet link is fed with (set when armed: FAILSAFE_FEED on the wall clock)
        self._feed_frame = FAILSAFE_FEED
        link.on_event(FrameType.FAILSAFE_REPLY, self._on_report)
        link.on_event(FrameType.PONG, self._on_pong)

    def request(self, payload: bytes, what: str, retries: int | None = None) -> FailsafeState:
        """One FAILSAFE exchange; its reply's state (TransportError when it is refused)."""
        frame = self.link.request(FrameType.FAILSAFE, payload, what,
                                  wire_size(4 + FailsafeState.SIZE), retries=retries)
        try:
            state = FailsafeState.decode(frame.payload)
        except FrameError as exc:
            raise TransportError(f"malformed FAILSAFE_REPLY ({exc}): reflash the bridge "
                                 "firmware (lm629 bridge flash)", port=self.link.url) from None
        if state.result != Result.OK:
            raise TransportError(f"the bridge refused {what} (result {state.result}): reflash "
                                 "the firmware that matches this host (lm629 bridge flash)",
                                 port=self.link.url)
        return state

    def open(self) -> None:
        """On open: report a latched trip (a warning) and acknowledge it, as reopening a
        channel does; then arm the failsafe as the URL says (or disarm it)."""
        if not self.available:
            return
        with self.link.lock:
            state = self.request(b"", "FAILSAFE (report)")
            if state.tripped:
                self.report = state
                log.warning("%s: %s; acknowledged by this open", self.link.url, state.describe())
                self.request(bytes((FailsafeCmd.ACKNOWLEDGE,)), "FAILSAFE (acknowledge)")
            self.arm()

    def arm(self) -> None:
        if not self.timeout_s:
            self.request(bytes((FailsafeCmd.DISARM,)), "FAILSAFE (disarm)")
            return
        ms = round(self.timeout_s * 1e3)
        self.request(bytes((FailsafeCmd.ARM,)) + ms.to_bytes(2, "big")
                       + bytes((self.action,)), f"FAILSAFE (arm {ms} ms)")
        wall = on_wall_clock(self.link)
        self.feed_period_s = self.timeout_s * (FEED_FRACTION if wall else SIMULATED_FEED_FRACTION)
        self._feed_frame = FAILSAFE_FEED if wall else SIMULATED_FEED
        # a far-side wait feeds only when it ends: each one shorter than the timeout
        self.link.far_wait_limit_s = self.timeout_s / 2
        if self.keepalive is None:
            # the keep-alive's protocol (when, skipped while a request is under way, which
            # clock); this says only what to send.  With failsafe_feed=script it is not
            # started: only a recording's wait turns it (a recording counts as alive only
            # while it streams)
            self.keepalive = KeepAlive(
                self.feed_period_s, self._send_feed, f"failsafe feeder {self.link.url}",
                last_heard=lambda: self.link.last_sent, clock=self.link.clock,
                busy=self.link.request_lock, unlocked=lambda: self.recording,
                before=self._before_feed)
            if self.feed_mode == "process":
                self.keepalive.start(self.link)

    def _before_feed(self) -> None:
        """At each turn of the keep-alive: the link's PROFILE top-ups, a trip heard and not
        told yet."""
        if not self.feed_period_s or self.link.closed:
            return
        if self.on_turn is not None:
            self.on_turn()
        self._log_untold()

    def _send_feed(self) -> None:
        """What the keep-alive sends: FAILSAFE_FEED (any frame feeds the bridge: a busy link
        pays nothing), then what is already waiting on the pipe is read (the answer to the
        last feed: a trip is heard here).  During a recording it goes out at once and nothing
        is read (the bridge takes it between rows; the recorder reads)."""
        link = self.link
        if not self.feed_period_s or link.closed:
            return
        if self.recording:
            self._feed_recording()
            return
        link.send_unsolicited(self._feed_frame)
        link.poll_events()

    def _feed_recording(self) -> None:
        self.link.send_unsolicited(FAILSAFE_FEED, when=lambda: self.recording)

    def feed(self) -> None:
        """Feed now (the script's own keep-alive, ``failsafe_feed=script``): one FAILSAFE_FEED,
        after any request under way in another thread has its answer."""
        link = self.link
        if not self.feed_period_s or link.closed:
            return
        if self.recording:
            self._feed_recording()
            return
        with link.request_lock:
            link.send_unsolicited(self._feed_frame)
            link.poll_events()

    def _on_report(self, frame: Frame) -> None:
        """A FAILSAFE_REPLY nobody waited for (the answer to a feed): a trip is news."""
        try:
            state = FailsafeState.decode(frame.payload)
        except FrameError:
            self.link.bad_frames += 1
            return
        if state.tripped:
            self._heard(state)

    def _on_pong(self, frame: Frame) -> None:
        """The answer to a simulated link's feed (a PING with seq 0): nothing to do."""

    def _heard(self, state: FailsafeState) -> None:
        """A trip is news: the next program raises it.  It goes to the log only if nobody is
        told by an error soon (:meth:`_log_untold`): a host that is busy in its own code
        still hears of it, and a command line says it once, not a notice and then the error."""
        if self.report != state:
            self.report = state
            self.news = state
            self._news_at = self.link.clock.now()
            self._news_logged = False

    def _log_untold(self, now: bool = False) -> None:
        """Log a trip heard :data:`UNTOLD_LOG_S` ago (``now``: at once) that no program has
        raised yet: nobody is calling the chip to be told."""
        news = self.news
        if news is None or self._news_logged:
            return
        if not now and self.link.clock.now() - self._news_at < UNTOLD_LOG_S:
            return
        self._news_logged = True
        log.warning("%s: %s; acknowledge it (lm629 clear, or clear_failsafe()) before "
                    "moving again", self.link.url, news.describe())

    def check(self) -> None:
        """Before a program: raise a trip heard and not told yet (:class:`FailsafeTripped`,
        once); and when this host itself was silent past the timeout (paused, suspended,
        starved of CPU, or a script that did not feed), ask the bridge first whether it
        tripped meanwhile, so that the first command after it hears the truth."""
        link = self.link
        if not self.feed_period_s:
            return
        silent = link.idle_s()
        if self.news is None and silent >= self.timeout_s:
            state = self.request(b"", "FAILSAFE (report)")
            if state.tripped:
                self._heard(state)
        news = self.news
        if news is not None:
            raise self._error(news, "nothing of this program ran", silent)

    def _error(self, state: FailsafeState | None, nothing: str,
               silent: float = 0.0) -> FailsafeTripped:
        """The one-line truth of a trip: what the bridge stopped and how, why the host was
        silent (as far as it knows), what did not happen, how to go on."""
        self.news = None
        what = state.describe() if state is not None else "the bridge's failsafe tripped"
        failure = self.keepalive.failure if self.keepalive is not None else None
        if self.feed_mode == "process" and failure is not None:
            why = f"this host's keep-alive kept turning but its feeds failed ({failure})"
        elif silent >= self.timeout_s:
            why = (f"this host sent nothing for {silent:.2f} s ("
                   + ("a script in failsafe_feed=script mode that neither called nor fed"
                      if self.feed_mode == "script" else
                      "paused, suspended or starved of CPU") + ")")
        elif self.feed_mode == "script":
            why = "the script neither called nor fed (failsafe_feed=script) for that long"
        elif self.feed_mode == "process" and self.keepalive is not None \
                and self.keepalive.last_stall_s >= self.timeout_s / 2:
            why = (f"this host's keep-alive was held up for {self.keepalive.last_stall_s:.2f} s "
                   "(paused, suspended or starved of CPU)")
        elif self.feed_mode == "process" and self.keepalive is not None:
            # this host kept feeding as far as it can tell: say so, not that it was silent
            why = (f"this host's keep-alive kept turning (worst gap "
                   f"{self.keepalive.worst_gap_s:.2f} s), so its feeds were lost on the line "
                   "or the far end was itself paused or starved of CPU")
        else:
            why = "the host was silent (paused, suspended, starved of CPU?)"
        stopped = state.stopped if state is not None else []
        try:
            how = FailsafeAction(state.action).name.lower() if state is not None else ""
        except ValueError:
            how = ""
        return FailsafeTripped(
            f"{what}; {why}; {nothing}. Acknowledge the trip with `lm629 clear` (Python: "
            "clear_failsafe()) before moving again", port=self.link.url, state=state,
            stopped=stopped, action=how, host_late_s=silent if silent >= self.timeout_s else 0.0)

    def state(self) -> FailsafeState | None:
        """The bridge's failsafe now (armed timeout, action, a latched trip), or None when
        the bridge has no failsafe."""
        if not self.available:
            return None
        with self.link.lock:
            return self.request(b"", "FAILSAFE (report)")

    def clear(self) -> FailsafeState | None:
        """Acknowledge a latched trip (the bridge takes trajectory commands again) and arm
        the failsafe again.  Returns the trip acknowledged (the one this open already
        acknowledged, if any), or None when there was none."""
        if not self.available:
            return None
        with self.link.lock:
            state = self.request(b"", "FAILSAFE (report)")
            found = state if state.tripped else self.report
            if state.tripped:
                self.request(bytes((FailsafeCmd.ACKNOWLEDGE,)), "FAILSAFE (acknowledge)")
            self.report = self.news = None
            self.arm()
            return found


    def tripped_error(self, nothing: str) -> FailsafeTripped:
        """The error for a request the bridge refused because its failsafe trip is latched
        (FAILSAFE_TRIPPED), with the trip it reports; ``nothing``: what did not happen."""
        try:
            state: FailsafeState | None = self.request(b"", "FAILSAFE (report)")
        except TransportError:
            state = None
        if state is not None and state.tripped and self.report != state:
            self.report = state
        return self._error(state, nothing)

    def close(self) -> None:
        """Stop the keep-alive and disarm the bridge's failsafe (a clean close: an axis left
        moving on purpose keeps moving).  A trip heard and never told goes to the log."""
        if self.keepalive is not None:
            self.keepalive.stop()
        self._log_untold(now=True)
        if self.feed_period_s:
            try:
                with self.link.lock:
                    self.request(bytes((FailsafeCmd.DISARM,)), "FAILSAFE (disarm)", retries=1)
            except (TransportError, OSError) as exc:
                log.debug("%s: failsafe not disarmed: %s", self.link.url, exc)
            self.feed_period_s = 0.0


__all__ = ["FAILSAFE_DEFAULT_S", "FAILSAFE_OPTIONS", "FEED_FRACTION",
           "FEED_MODES", "SIMULATED_FEED_FRACTION", "FailsafeOptions", "LinkFailsafe", "failsafe_options"]
