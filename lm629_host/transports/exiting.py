"""A normal end of the interpreter closes the links a script left open.

A script may end without ``close()`` (``chip = lm629_host.open(...)``, a move, the end of the
file).  Left alone, its link's keep-alive thread dies with the interpreter, the bridge hears
nothing for its failsafe time, stops every chip and latches a trip, and the next command
reports a dead host: a report that trains users to ignore the real ones.  An interpreter that
ends normally (the end of the script, ``sys.exit``, an uncaught exception) runs :mod:`atexit`,
and there every transport still open is closed as leaving a ``with`` block by an exception
closes it: each chip that still carries out a trajectory is stopped (abrupt stop, the PID
holding: the action each chip registered with :func:`stop_at_exit`), then ``close()`` disarms
the far side's failsafe and releases the port, and nothing is reported.  A chip that cannot
be stopped (the link failed) keeps its link from that clean close: the failsafe, still armed,
stops it once the process has gone, and the next process is told.  A process killed
(SIGKILL, the OOM killer, SIGTERM's default), crashed (a signal, ``os._exit``) or paused runs
no atexit: the failsafe still trips, and the next process is still told.

One registry, strong references: a transport opened and not closed is kept until it is
closed or the interpreter ends (its keep-alive thread keeps it alive anyway).  A forked child
does not close its parent's links (the pid is checked).
"""

from __future__ import annotations

import atexit
import logging
import os
import threading
from collections.abc import Callable, Iterable
from typing import Protocol


class OpenLink(Protocol):
    """What this module needs of a transport (:class:`~lm629_host.transports.base.Transport`:
    that module registers here, so this one does not import it back)."""

    url: str

    def close(self) -> None: ...

log = logging.getLogger("lm629_host.transports")

#: every transport open in this process, with what to do before it closes at exit (per key:
#: a chip select, so that the last object made for a chip is the one that stops it)
_OPEN: dict[OpenLink, dict[object, Callable[[], object]]] = {}
_LOCK = threading.Lock()
_PID = os.getpid()
_registered = False


def track(transport: OpenLink) -> None:
    """Count ``transport`` as open (called by every transport as it is made)."""
    global _registered
    with _LOCK:
        _OPEN.setdefault(transport, {})
        if not _registered:
            atexit.register(close_left_open)
            _registered = True


def forget(transport: OpenLink) -> None:
    """``transport`` closed: nothing to do for it at exit."""
    with _LOCK:
        _OPEN.pop(transport, None)


def stop_at_exit(transport: OpenLink, key: object, action: Callable[[], object]) -> None:
    """Run ``action`` (stop a chip if it moves) before ``transport`` is closed at exit; a later
    action with the same ``key`` replaces the earlier one.  An action that returns False (the
    chip may still move) keeps the link from a clean close: the far side's failsafe, left
    armed, stops it when the process has gone."""
    with _LOCK:
        if transport in _OPEN:
            _OPEN[transport][key] = action


def left_open() -> list[OpenLink]:
    """The transports open now, in the order they were made."""
    with _LOCK:
        return list(_OPEN)


def close_left_open(only: Iterable[OpenLink] | None = None) -> int:
    """Stop what moves and close every transport still open (the atexit hook).  Never
    raises: an exit must finish.  Returns how many were closed.  ``only``: just these of
    them, as the hook would (a test that plays one script's end in a process whose other
    links stay open: the crossings machine)."""
    if os.getpid() != _PID:  # a forked child: the links are its parent's
        return 0
    with _LOCK:
        items = list(_OPEN.items())
    if only is not None:
        chosen = list(only)
        items = [(t, a) for t, a in items if any(t is c for c in chosen)]
    for transport, actions in items:
        safe = True
        for action in list(actions.values()):
            try:
                safe = action() is not False and safe
            except BaseException as exc:  # noqa: BLE001 - the next link must still close
                log.warning("%s: could not stop a chip at exit: %s", transport.url, exc)
                safe = False
        if not safe:  # a chip may still move: its link is left to the far side's failsafe
            log.warning("%s: a chip could not be stopped at exit: left to the bridge's "
                        "failsafe (it stops every chip when this process has gone)",
                        transport.url)
            forget(transport)
            continue
        try:
            transport.close()
        except BaseException as exc:  # noqa: BLE001 - the next link must still close
            log.warning("%s: could not close at exit: %s", transport.url, exc)
        forget(transport)
    if items:
        log.debug("closed %d link(s) left open at exit", len(items))
    return len(items)


__all__ = ["close_left_open", "forget", "left_open", "stop_at_exit", "track"]
