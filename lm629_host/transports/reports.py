"""What a transport reports, as plain records: its work counters (:class:`Stats`), a
recording's rows (:class:`RawRow`), a far-side schedule's state (:class:`ProfileState`), a
port found (:class:`PortInfo`) and a line of ``lm629 doctor`` (:class:`Check`).  Apart from
the contract in :mod:`lm629_host.transports.base` (which hands them on) so that the contract
reads as what a transport does, and these as what it says."""

from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass
class Stats:
    """Work counters of a transport (``chip.transport.stats``)."""

    programs: int = 0  #: bus programs executed
    round_trips: int = 0  #: request/answer exchanges with the far side (USB transfers pairs, frames)
    bytes_out: int = 0  #: bytes sent to the far side
    bytes_in: int = 0  #: bytes received from the far side
    bus_cycles: int = 0  #: /RD or /WR strobes plus /RST pulses on the chip's bus
    busy_polls: int = 0  #: status reads made only to check the busy bit
    retries: int = 0  #: requests repeated after a link fault

    def as_dict(self) -> dict[str, int]:
        return asdict(self)

    def reset(self) -> None:
        for k in self.as_dict():
            setattr(self, k, 0)

    def __str__(self) -> str:
        return " ".join(f"{k}={v}" for k, v in self.as_dict().items())


@dataclass(frozen=True)
class RawRow:
    """One row of a recording as a transport delivers it (:meth:`Transport.record_rows`):
    ``index`` is the row's slot (0 at the first row asked, one more each period: a missing
    index is a row lost, never filled in), ``t`` the time it was sampled in seconds on the clock
    that timed it (the far side's where the transport records there), and what the sample
    program read."""

    index: int
    t: float
    words: tuple[int, ...]
    statuses: tuple[int, ...]


#: what the host-polled recording says of itself on a wall clock (FT232H, an old bridge)
HOST_POLLED_NOTE = (
    "rows are read by the host, one exchange each, and stamped with the host's clock when the "
    "exchange starts: the spacing jitters by what an exchange takes (USB latency included), a "
    "row is never faster than one exchange, and a period the host could not keep is a gap")


@dataclass(frozen=True)
class ProfileState:
    """What a far side reports of a shaped move's pieces it issues on its own timer
    (:meth:`Transport.profile`): pieces issued and still pending, the largest lateness of an
    issued piece against its time on the far side's clock, and whether the schedule was
    cancelled (a stop reached the chip before its last piece)."""

    issued: int
    pending: int
    late_max_s: float
    cancelled: bool = False
    #: pieces the host still holds, to hand over as the far side's schedule empties (a
    #: schedule longer than the far side holds, streamed)
    queued: int = 0


@dataclass(frozen=True)
class PortInfo:
    """A candidate port found by a transport module's ``list_ports()`` (for ``lm629 list``)."""

    url: str  #: what to pass to ``--port``
    description: str  #: what it is (USB ids, product string, firmware version when probed)
    usable: bool = True  #: False when it was found but cannot be opened (``problem`` says why)
    problem: str = ""


@dataclass(frozen=True)
class Check:
    """One line of ``lm629 doctor``: a transport module's ``doctor()`` returns a list of these."""

    name: str
    ok: bool
    message: str


__all__ = ["HOST_POLLED_NOTE", "Check", "PortInfo", "ProfileState", "RawRow", "Stats"]
