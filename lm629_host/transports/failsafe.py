"""The link's failsafe, the host's half: arm it at open, feed it while the host lives, read and
acknowledge a trip (PROTOCOL.md, FAILSAFE).  The bridge keeps the timer and stops the chips;
this module only talks to it through the link's session.
"""

from __future__ import annotations

import logging
import threading
from typing import TYPE_CHECKING

from lm629_host.bridge.protocol import (
    FAILSAFE_FEED,
    FAILSAFE_MAX_MS,
    FAILSAFE_MIN_MS,
    FailsafeAction,
    FailsafeCmd,
    FailsafeState,
    FrameError,
    FrameType,
    Result,
    wire_size,
)
from lm629_host.clock import WallClock
from lm629_host.errors import FailsafeTripped, TransportError
from lm629_host.urls import Option, parse_options, query_params

if TYPE_CHECKING:
    from lm629_host.transports.session import LinkSession

log = logging.getLogger("lm629_host.bridge.protocol")

#: the failsafe's URL options, taken by every bridge port (``failsafe=0``: disarmed)
FAILSAFE_DEFAULT_S = 0.5
FAILSAFE_OPTIONS = (
    Option("failsafe", "float", FAILSAFE_DEFAULT_S, 0, FAILSAFE_MAX_MS / 1e3, "s"),
    Option("failsafe_action", "str", "abrupt", choices=tuple(a.name.lower() for a in FailsafeAction)))
FAILSAFE_OPTION_NAMES = frozenset(o.name for o in FAILSAFE_OPTIONS)
#: the feeder sends when the link has been idle this fraction of the failsafe's timeout: three
#: feeds may be lost on the line before the bridge trips
FEED_FRACTION = 0.25


def failsafe_options(url: str) -> tuple[float, FailsafeAction]:
    """``failsafe=SECONDS`` (0: off, else 0.05..10) and ``failsafe_action=abrupt|smooth|off``
    of a bridge port's URL; ValueError naming the option (the other options are not looked at)."""
    opts = parse_options(url, FAILSAFE_OPTIONS,
                         ignore=set(query_params(url)) - FAILSAFE_OPTION_NAMES)
    seconds = opts["failsafe"]
    if seconds and round(seconds * 1e3) < FAILSAFE_MIN_MS:
        raise ValueError(f"{url}: failsafe={seconds:g} is outside 0 (off) or "
                         f"{FAILSAFE_MIN_MS / 1e3:g}..{FAILSAFE_MAX_MS / 1e3:g} s")
    return seconds, FailsafeAction[opts["failsafe_action"].upper()]


class LinkFailsafe:
    """The failsafe of one link: what the URL asked for, whether the bridge has one, the trip
    this open found, and the feeder."""

    def __init__(self, link: LinkSession) -> None:
        self.link = link
        #: the failsafe asked for by the URL (seconds, 0: off) and its action
        self.timeout_s, self.action = failsafe_options(link.url)
        self.available = False  #: the bridge has one (HELLO's capability bit 9)
        #: the trip this open found latched (and acknowledged), or one the feeder saw
        self.report: FailsafeState | None = None
        #: the feeder sends after the link was idle this long (0: no feeder)
        self.feed_period_s = 0.0
        self._feeder: threading.Thread | None = None
        self._feeder_stop = threading.Event()
        #: set while a recording streams: then the only feed is FAILSAFE_FEED
        self.recording = False
        self._tx_lock = threading.Lock()  # the feeder writes a recording's feed from its thread

    def request(self, payload: bytes, what: str, retries: int | None = None) -> FailsafeState:
        """One FAILSAFE exchange; its reply's state (TransportError when it is refused)."""
        self.link._resync()
        frame = self.link._exchange(FrameType.FAILSAFE, payload, self.link.reply_timeout(
            wire_size(4 + len(payload)), wire_size(4 + FailsafeState.SIZE)), what,
            self.link.retries if retries is None else retries)
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
        self.feed_period_s = self.timeout_s * FEED_FRACTION
        # a far-side wait feeds only when it ends: each one shorter than the timeout
        self.link.far_wait_limit_s = self.timeout_s / 2
        if isinstance(self.link._inner_clock, WallClock):
            if self._feeder is None:
                self._feeder = threading.Thread(target=self._feed_loop, daemon=True,
                                                name=f"lm629 failsafe feeder {self.link.url}")
                self._feeder.start()
        else:
            self.link.feed_on_sleep()

    def feed_if_due(self) -> None:
        """Feed the failsafe when the link has been idle for :attr:`feed_period_s` (any
        exchange feeds it: busy links pay nothing).  A trip seen here is kept in
        :attr:`report` and logged once."""
        if not self.feed_period_s or self.link._closed or self.recording:
            return
        if self.link.clock.now() - self.link._last_tx < self.feed_period_s:
            return
        try:
            state = self.request(b"", "FAILSAFE (feed)", retries=1)
        except TransportError as exc:
            log.debug("%s: failsafe feed failed: %s", self.link.url, exc)
            return
        if state.tripped and self.report != state:
            self.report = state
            log.warning("%s: %s; acknowledge it (lm629 clear, or clear_failsafe()) before "
                        "moving again", self.link.url, state.describe())

    def _feed_loop(self) -> None:
        """The feeder thread (wall-clock links): while the process lives, feed whenever the
        link is idle; never waits for the lock (a program under way feeds by itself)."""
        while not self._feeder_stop.wait(self.feed_period_s / 2):
            if self.link._closed:
                return
            if self.recording:
                self.feed_recording()
                continue
            self.link.keep_alive(self.feed_if_due, "failsafe feeder")

    def feed_recording(self) -> None:
        """During a recording: FAILSAFE_FEED, the one frame a recording takes without
        ending, when the link has been quiet for a feed period."""
        if not self.feed_period_s or self.link.clock.now() - self.link._last_tx < self.feed_period_s:
            return
        with self._tx_lock:
            if not self.recording:
                return
            self.link._last_tx = self.link.clock.now()
            try:
                self.link.pipe.write(FAILSAFE_FEED)
            except OSError:
                return
            self.link.stats.bytes_out += len(FAILSAFE_FEED)

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
            self.report = None
            self.arm()
            return found


    def tripped_error(self, nothing: str) -> FailsafeTripped:
        """The error for a request the bridge refused because its failsafe trip is latched
        (FAILSAFE_TRIPPED), with the trip it reports; ``nothing``: what did not happen."""
        try:
            state: FailsafeState | None = self.request(b"", "FAILSAFE (report)")
        except TransportError:
            state = None
        what = state.describe() if state is not None else "the bridge's failsafe tripped"
        return FailsafeTripped(
            f"{what}; {nothing}. The host was silent (suspended, hung?): acknowledge the trip "
            "with `lm629 clear` (Python: clear_failsafe()) before moving again",
            port=self.link.url, state=state)

    def close(self) -> None:
        """Stop the feeder and disarm the bridge's failsafe (a clean close: an axis left moving
        on purpose keeps moving)."""
        self._feeder_stop.set()
        if self.feed_period_s:
            try:
                with self.link.lock:
                    self.request(bytes((FailsafeCmd.DISARM,)), "FAILSAFE (disarm)", retries=1)
            except (TransportError, OSError) as exc:
                log.debug("%s: failsafe not disarmed: %s", self.link.url, exc)
            self.feed_period_s = 0.0


__all__ = ["FAILSAFE_DEFAULT_S", "FAILSAFE_OPTIONS", "FAILSAFE_OPTION_NAMES", "FEED_FRACTION",
           "LinkFailsafe", "failsafe_options"]
