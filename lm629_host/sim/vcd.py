"""The simulated bus as a VCD file: ``vcd=FILE`` on every simulated URL (``sim://``,
``sim+emu://``, ``sim+avr://``, ``sim+ftdi://``) and ``lm629 --vcd FILE``.

What a logic analyzer clipped onto the chip's pins would record, written so that sigrok's VCD
input, PulseView and the ``lm629`` protocol decoder (``lm629_host/sigrok/lm629``) read it as
they read a capture: one 1-bit signal a line, named as the decoder's channel ids (``d0``..``d7``,
``cs``, ``rd``, ``wr``, ``ps``, ``rst``, ``hi``; on a bus of several chips ``cs1``, ``hi1``...
for chip 1 onward, so the decoder runs once per chip with ``cs=cs1``).

Where the levels come from, per simulator:

* ``sim://`` and ``sim+emu://``: the chip model's strobes, on the model's clock
  (:class:`ProbedBus`).  Each strobe is drawn as one bus cycle of the transport's cycle time
  ending at the tick the model took it: /CS and /PS set up, the strobe low for half the
  cycle, read data driven after a quarter (the access time), everything released at the end.
  Every busy poll is made (the transport's busy skip is turned off), so the file shows the
  polls a real host makes.
* ``sim+avr://``: the AVR's port pins as the compiled firmware drives them in simavr, at AVR
  cycle resolution (the harness logs every change of a bus line, ``fitl.c``).
* ``sim+ftdi://``: the emulated FT232H's ADBUS and ACBUS pins as its MPSSE engine drives them,
  on the emulated clock.

A line nobody drives reads 1 (the pull-ups docs/bridge.md recommends on D0-D7).  The timescale
is 10 ns by default (``vcd_timescale=``, ns): sigrok's VCD input makes one sample per
timescale unit, so a finer one multiplies the samples of a long capture.  Nothing here runs
unless ``vcd=`` is given: the simulators' hot paths carry no probe otherwise.
"""

from __future__ import annotations

import atexit
import os
import weakref
from pathlib import Path
from collections.abc import Sequence
from typing import IO, Any, NoReturn, cast

from lm629_host.urls import Option, PortURL, query_params, read_rows
from lm629_host.sim.model import ChipBus, ChipModel

def _vcd_file(text: str, url: Any) -> str:
    if not text.strip():
        raise ValueError(f"{url}: vcd= is empty: give the file to write (vcd=bus.vcd) or "
                         "leave vcd= out")
    return text


#: the URL options (any simulated URL): the file, and the VCD's time unit in ns
OPTIONS = (Option("vcd", "str", "", check=_vcd_file),
           Option("vcd_timescale", "int", 10, 1, 1000, "ns"))
#: the time units pyvcd (and the VCD format) allow: 1, 10 or 100 of a unit
_TIMESCALES = (1, 10, 100, 1000)

#: the decoder's channel ids for the lines every chip shares
DATA = tuple(f"d{i}" for i in range(8))


def cs_name(chip: int) -> str:
    """The /CS signal of chip ``chip``: ``cs`` for chip 0 (the decoder's own id), ``cs1``..."""
    return "cs" if chip == 0 else f"cs{chip}"


def hi_name(chip: int) -> str:
    return "hi" if chip == 0 else f"hi{chip}"


def vcd_of(url: str | PortURL, options: dict[str, Any] | None = None) -> tuple[str, int] | None:
    """The URL's ``vcd=`` file and ``vcd_timescale=`` (None: no VCD asked for); ``options``:
    the URL as its transport parsed it (None: these rows read from ``url``)."""
    q = query_params(url)
    if "vcd" in q:
        _vcd_file(q["vcd"], url)
    if not q.get("vcd"):
        if "vcd_timescale" in q:
            raise ValueError(f"{url}: vcd_timescale= without vcd=FILE")
        return None
    opts = read_rows(url, OPTIONS) if options is None else options
    if opts["vcd_timescale"] not in _TIMESCALES:
        raise ValueError(f"{url}: vcd_timescale={opts['vcd_timescale']}: a VCD time unit is "
                         f"1, 10, 100 or 1000 ns")
    folder = Path(opts["vcd"]).parent
    if not folder.is_dir():
        raise ValueError(f"{url}: vcd={opts['vcd']}: the directory {str(folder)!r} does not "
                         "exist")
    _check_writable(url, Path(opts["vcd"]))
    return opts["vcd"], opts["vcd_timescale"]


def _check_writable(url: str | PortURL, path: Path) -> None:
    """ValueError (bad usage, before the simulator is built) when ``path`` cannot be written:
    a directory, a file or a folder without write permission, or a file system that takes
    no new file (/proc, a read-only mount: only trying tells, so a new file is made and
    removed again, as the writer makes it a moment later)."""
    def refuse(why: str) -> NoReturn:
        raise ValueError(f"{url}: vcd={path}: {why}: give a file in a folder you can write "
                         "(vcd=bus.vcd)")
    if path.is_dir():
        refuse("that is a directory")
    if path.exists():
        if not os.access(path, os.W_OK):
            refuse("the file is not writable")
        return
    try:
        with path.open("x"):
            pass
        path.unlink()
    except OSError as exc:
        refuse(f"cannot create it ({exc.strerror or exc})")


_open_writers: weakref.WeakSet[BusVcd] = weakref.WeakSet()


@atexit.register
def _close_all() -> None:  # pragma: no cover - what a program that never closed its port gets
    for w in list(_open_writers):
        w.close()


class BusVcd:
    """Levels of the bus lines, written to a VCD file with pyvcd.

    Sources call :meth:`set` with a time in ns and the lines that change; changes at one
    timestamp are merged (the last level wins), so a line that goes high and low again at the
    same instant leaves no glitch.  Times that run backwards are clamped to the last one."""

    def __init__(self, path: str, *, chips: int = 1, his: int | None = None,
                 timescale_ns: int = 10, comment: str = "") -> None:
        try:
            from vcd import VCDWriter
        except ImportError:  # pragma: no cover - the extra is part of the test install
            raise RuntimeError("vcd= needs pyvcd: pip install 'lm629-host[vcd]'") from None
        self.path = path
        self.timescale_ns = timescale_ns
        self._file: IO[str] = open(path, "w")  # noqa: SIM115 - closed by close()
        self._writer = VCDWriter(self._file, timescale=f"{timescale_ns} ns", date="",
                                 comment=comment or "lm629-host simulated bus")
        init = {n: 1 for n in DATA}
        for k in range(chips):
            init[cs_name(k)] = 1
        init.update(rd=1, wr=1, ps=1, rst=1)
        for k in range(chips if his is None else his):
            init[hi_name(k)] = 0
        self._vars = {n: self._writer.register_var("lm629", n, "wire", size=1, init=v)
                      for n, v in init.items()}
        self.level: dict[str, int] = dict(init)  #: the levels as of the last :meth:`set`
        self._written = dict(init)
        self._pending: dict[str, int] = {}
        self._t = 0  #: the current timestamp, in time units
        self.closed = False
        _open_writers.add(self)

    def units(self, ns: float) -> int:
        return round(ns / self.timescale_ns)

    def set(self, ns: float, levels: dict[str, int]) -> None:
        """The lines of ``levels`` take these levels (0/1) at ``ns``."""
        t = self.units(ns)
        if t > self._t:
            self._flush()
            self._t = t
        self._pending.update(levels)
        self.level.update(levels)

    def data(self, ns: float, byte: int) -> None:
        """D0-D7 carry ``byte`` from ``ns`` on."""
        self.set(ns, {n: (byte >> i) & 1 for i, n in enumerate(DATA)})

    def _flush(self) -> None:
        w, written, t = self._writer, self._written, self._t
        for name, v in self._pending.items():
            if written[name] != v:
                w.change(self._vars[name], t, v)
                written[name] = v
        self._pending.clear()

    def close(self, ns: float | None = None) -> None:
        """Write what is pending and close the file (``ns``: the capture's end time)."""
        if self.closed:
            return
        self._flush()
        self.closed = True
        end = self._t if ns is None else max(self._t, self.units(ns))
        self._writer.close(end)
        self._file.close()
        _open_writers.discard(self)


class _ProbedChip:
    """One chip of a :class:`ProbedBus`: its strobes are drawn with its own /CS, then passed
    on; everything else is the chip's own (reads and writes of attributes alike)."""

    __slots__ = ("_bus", "_chip", "_index")

    def __init__(self, chip: ChipModel, bus: ProbedBus, index: int) -> None:
        object.__setattr__(self, "_chip", chip)
        object.__setattr__(self, "_bus", bus)
        object.__setattr__(self, "_index", index)

    def read_status(self) -> int:
        b = self._chip.read_status()
        self._bus.draw(self._index, "rd", 0, b, True)
        return b

    def read_data(self) -> int:
        b = self._chip.read_data()
        self._bus.draw(self._index, "rd", 1, b, True)
        return b

    def write_command(self, byte: int) -> None:
        self._bus.draw(self._index, "wr", 0, byte & 0xFF, False)
        self._chip.write_command(byte)

    def write_data(self, byte: int) -> None:
        self._bus.draw(self._index, "wr", 1, byte & 0xFF, False)
        self._chip.write_data(byte)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._chip, name)

    def __setattr__(self, name: str, value: Any) -> None:
        setattr(self._chip, name, value)


class ProbedBus(ChipBus):
    """A :class:`ChipBus` whose strobes, /RST pulses and HI lines are drawn into a
    :class:`BusVcd` on the model's clock, for the simulators that drive the model one strobe at
    a time (``sim://``, ``sim+emu://``).  Its ``chips`` draw their own strobes, so a simulator
    that strobes the bus and one that strobes a chip of it (the Python bridge) are drawn
    alike.  ``cycle_clocks``: the simulator's bus cycle, in chip clocks: each strobe is drawn
    as that cycle ending at the tick of the model call."""

    def __init__(self, chips: Sequence[ChipModel], lines: int | None, vcd: BusVcd,
                 cycle_clocks: int) -> None:
        super().__init__(chips, lines)
        self.chips = [cast(ChipModel, _ProbedChip(c, self, k)) for k, c in enumerate(self.chips)]
        self.vcd = vcd
        self.cycle_clocks = max(1, cycle_clocks)
        self._ns_per_tick = 1e9 / self.clock_hz
        self._free_ns = 0.0  #: where the last drawn cycle ended
        self._his = self.his
        self.vcd.set(self.tick * self._ns_per_tick, {})

    def _window(self) -> tuple[float, float]:
        """The (start, end) in ns of a bus cycle that ends now (never before the last one)."""
        end = self.tick * self._ns_per_tick
        start = max(end - self.cycle_clocks * self._ns_per_tick, self._free_ns)
        end = max(end, start + 4 * self.vcd.timescale_ns)
        self._free_ns = end
        return start, end

    def draw(self, chip: int, strobe: str, ps: int, byte: int, read: bool) -> None:
        """One strobe of chip ``chip`` ending now: /CS and /PS set up, the strobe low for half
        the cycle, a read's byte driven after a quarter (the access time), all released."""
        v = self.vcd
        t0, t1 = self._window()
        w = t1 - t0
        cs = cs_name(chip)
        v.set(t0, {cs: 0, "ps": ps})
        if not read:
            v.data(t0, byte)
        v.set(t0 + w / 4, {strobe: 0})
        if read:
            v.data(t0 + w / 2, byte)
        v.set(t0 + 3 * w / 4, {strobe: 1})
        v.set(t1, {cs: 1, "ps": 1})
        v.data(t1, 0xFF)  # released: the pull-ups
        self._draw_hi(t1)

    def _draw_hi(self, ns: float) -> None:
        his = self.his
        if his != self._his:
            self._his = his
            self.vcd.set(ns, {hi_name(k): int(h) for k, h in enumerate(his)})

    def reset_pulse(self) -> None:
        """/RST low for the 8 clocks before now (the transports hold it that long), rising now."""
        end = self.tick * self._ns_per_tick
        start = max(end - 8 * self._ns_per_tick, self._free_ns)
        end = max(end, start + 2 * self.vcd.timescale_ns)
        self._free_ns = end
        self.vcd.set(start, {"rst": 0})
        self.vcd.set(end, {"rst": 1})
        super().reset_pulse()

    def advance_to(self, tick: int) -> None:
        super().advance_to(tick)
        # drawn where the next strobe's cycle may begin, so that its levels never go back in
        # time (a sample's HI edge is shown at most one bus cycle early)
        self._draw_hi(max((self.tick - self.cycle_clocks) * self._ns_per_tick, self._free_ns))

    def close(self) -> None:
        self.vcd.close(self.tick * self._ns_per_tick)


def probe(model: ChipModel | ChipBus, path: str, timescale_ns: int,
          cycle_clocks: int) -> ProbedBus:
    """``model`` (one chip or a bus) behind a :class:`ProbedBus` writing ``path``."""
    chips = model.chips if isinstance(model, ChipBus) else [model]
    lines = model.lines if isinstance(model, ChipBus) else 1
    vcd = BusVcd(path, chips=lines, his=len(chips), timescale_ns=timescale_ns)
    return ProbedBus(chips, lines, vcd, cycle_clocks)


def close_probe(model: Any) -> None:
    """Close the VCD of ``model`` if it is a :class:`ProbedBus` (a transport's close)."""
    if isinstance(model, ProbedBus):
        model.close()


__all__ = ["BusVcd", "DATA", "OPTIONS", "ProbedBus", "close_probe", "cs_name",
           "hi_name", "probe", "vcd_of"]
