"""The compiled bridge firmware in simavr, wired to a :class:`~lm629_host.sim.model.ChipModel`.

``firmware_bridge/harness/fitl.c`` (built by ``make -C firmware_bridge`` into
``build/libfitl.so``) runs the firmware ELF in libsimavr, instruction by instruction, decodes the
chip-select, port-select, read, write and reset edges in C, and calls :meth:`AvrSim._on_bus`
here once per bus cycle; the model answers reads, and the harness drives the byte onto the data
pins only after the chip's read access time.  The UART is fed in-process.

:class:`AvrPipe` is the :class:`~lm629_host.bridge.protocol.Pipe` of the ``sim+avr://`` transport: bytes
written go to the simulated UART, ``read`` runs the AVR (in C, many instructions per call) until
a reply frame is out or the timeout passes, and its clock is the AVR's simulated time.  Nothing
here sleeps on the wall clock.

The model's time follows the AVR's: before each strobe it is advanced to
``avr_cycle * clock_hz // 16 MHz``.  The HI line the firmware reads is the model's HI as of the
last bus cycle (the firmware reads HI right after its program's last strobe).

Building, checking and loading the firmware and the harness is :mod:`lm629_host.sim.harness`,
which also keeps a closed sim's AVR (``IDLE_AVRS``) for the next open of the same image: powered
on again, as new in every way the firmware or a test can see.

Several chips: ``model`` may be a :class:`~lm629_host.sim.model.ChipBus`; the harness names the
chip whose /CS was low with each cycle (the firmware's chip-select pins, from the pin map) and
the bus routes the strobe to it; /RST reaches all of them; every chip's HI goes back to its pin.
"""

from __future__ import annotations

import ctypes
import math
import subprocess
from pathlib import Path

from lm629_host.bridge.protocol.constants import CODE_BYTES, CODE_SLOTS, PROFILE_MAX_SCHEDULE
from lm629_host.clock import Clock
from lm629_host.errors import ProtocolViolation, TransportError
from lm629_host.sim.harness import (BUS_CALLBACK, IDLE_AVRS, HarnessError, check_firmware,
                                    firmware_path, image_key, load_library)
from lm629_host.sim.wiring import Miswiring
from lm629_host.sim.model import ChipBus, ChipModel, chips_of
from lm629_host.sim.vcd import DATA as VCD_DATA
from lm629_host.sim.vcd import BusVcd, cs_name, hi_name

#: the ATmega328P's clock on an Uno / Nano
CPU_HZ = 16_000_000

# bus cycle kinds (fitl.c)
STATUS, COMMAND, WRITE, READ, RESET = range(5)


class AvrSim:
    """One simulated ATmega328P running ``firmware`` with ``model`` on its LM629 bus.

    ``strict``: a timing violation of the chip's bus minimums seen by the harness raises
    :class:`~lm629_host.errors.ProtocolViolation` (default: the model's own ``strict``)."""

    def __init__(self, model: ChipModel | ChipBus, firmware: Path | str | None = None, *,
                 strict: bool | None = None, wiring: Miswiring | None = None) -> None:
        self.model = model
        #: ``wiring=``: the data lines between the AVR's pins and the chip, bent here where
        #: the harness hands the pins' byte to the chip and the chip's byte to the pins
        self.wiring = wiring
        self._lib = load_library()
        self.firmware = Path(firmware) if firmware else firmware_path()
        if not self.firmware.exists():
            raise HarnessError(f"firmware image {self.firmware} not found: run "
                               "`make -C firmware_bridge`")
        check_firmware(self.firmware)
        self.strict = model.params.strict if strict is None else strict
        self._error: BaseException | None = None
        self._cb = BUS_CALLBACK(self._on_bus)  # referenced for as long as the simulation lives
        self._key = image_key(self.firmware)
        self._h = IDLE_AVRS.take(self._key)
        if self._h and self._lib.fitl_restart(self._h, self._cb):
            self._lib.fitl_free(self._h)  # it did not boot again: a new one says why, if so
            self._h = None
        #: this sim's AVR was a closed sim's, powered on again (``IDLE_AVRS``)
        self.reused = bool(self._h)
        if not self._h:
            self._h = self._lib.fitl_new(str(self.firmware).encode(), self._cb)
        if not self._h:
            raise HarnessError(f"simavr cannot run {self.firmware}: "
                               f"{self._lib.fitl_error().decode()}")
        self._ratio = model.clock_hz / CPU_HZ
        #: chips on /CS 0..n-1; a strobe on another /CS finds a floating bus
        self._wired = len(chips_of(model))
        self._buf = (ctypes.c_uint8 * 8192)()
        self.reset_low_clocks: list[int] = []
        #: set to a list to record every bus cycle as (kind, value, AVR cycle)
        self.bus_log: list[tuple[int, int, int]] | None = None
        #: the VCD the port pins go to (:meth:`write_vcd`), None: the harness logs no pins
        self.vcd: BusVcd | None = None

    # ------------------------------------------------------------------ bus (from C)
    def _on_bus(self, kind: int, value: int, cycle: int) -> int:
        try:
            if self.bus_log is not None:
                self.bus_log.append((kind, value, cycle))
            m = self.model
            tick = cycle * m.clock_hz // CPU_HZ
            if tick > m.tick:
                m.advance_to(tick)
            chip, kind = kind >> 4, kind & 0x0F
            w = self.wiring
            if w is not None and kind in (COMMAND, WRITE):
                value = w.to_chip(value)
            if kind == RESET:
                low = math.floor(value * self._ratio)
                self.reset_low_clocks.append(low)
                if low < 8:
                    raise ProtocolViolation(f"/RST held low for {low} chip clocks; the chip "
                                            "needs at least 8")
                m.reset_pulse()
                r = 0
            elif chip >= self._wired:
                # a /CS with no chip behind it (the failsafe's scan strobes every select): the
                # bus floats, as on a board, so reads find the pull-ups and writes go nowhere
                r = 0 if kind in (COMMAND, WRITE) else 0xFF if w is None else w.to_host(0xFF)
            else:
                if isinstance(m, ChipBus):
                    m.select(chip)
                if kind == STATUS:
                    r = m.read_status() if w is None else w.to_host(m.read_status())
                elif kind == READ:
                    r = m.read_data() if w is None else w.to_host(m.read_data())
                elif kind == COMMAND:
                    m.write_command(value)
                    r = 0
                else:
                    m.write_data(value)
                    r = 0
            if isinstance(m, ChipBus):
                his = 0
                for k, c in enumerate(m.chips):
                    if c.hi:
                        his |= 0x100 << k
                return (r & 0xFF) | his
            return (r & 0xFF) | (0x100 if m.hi else 0)
        except BaseException as exc:  # noqa: BLE001 - ctypes would swallow it: keep it, stop the run
            self._error = exc
            return -1

    # ------------------------------------------------------------------ running
    @property
    def cycle(self) -> int:
        return int(self._lib.fitl_cycle(self._h))

    @property
    def now(self) -> float:
        """Simulated seconds since the AVR came out of reset."""
        return self.cycle / CPU_HZ

    def violations(self) -> tuple[int, str]:
        """(number of bus timing violations seen, the first one described)."""
        buf = ctypes.create_string_buffer(256)
        n = self._lib.fitl_violations(self._h, buf, 256)
        return int(n), buf.value.decode()

    def _check(self, rc: int) -> None:
        if self._error is not None:
            exc, self._error = self._error, None
            raise exc
        if rc == -2:
            raise HarnessError(f"the firmware {self.firmware} crashed in simavr at cycle "
                               f"{self.cycle}")
        if self.strict:
            n, first = self.violations()
            if n:
                raise ProtocolViolation(f"bridge bus timing: {n} violation(s), first: {first}")

    def run_until(self, cycle: int, *, frames: bool = False) -> bool:
        """Run the AVR up to ``cycle``; with ``frames`` stop early when the firmware has sent
        a frame delimiter (True then)."""
        rc = self._lib.fitl_run(self._h, cycle, 1 if frames else 0)
        if self.vcd is not None:
            self._drain_pins()
        self._check(rc)
        return rc == 1

    # ------------------------------------------------------------------ the pins as a VCD
    def write_vcd(self, path: str, timescale_ns: int = 10) -> None:
        """From now on, every level the bus lines take goes to the VCD ``path``, at the AVR's
        cycle resolution: D0-D7, /RD, /WR, /PS, /RST, the /CS and HI lines of the chips."""
        chips = len(chips_of(self.model))
        self.vcd = BusVcd(path, chips=chips, timescale_ns=timescale_ns,
                          comment=f"lm629-host: bridge firmware {self.firmware.name} in simavr")
        self._pin_cycles = (ctypes.c_uint64 * 4096)()
        self._pin_levels = (ctypes.c_uint32 * 4096)()
        self._lib.fitl_pin_log(self._h, 1)
        self._drain_pins()

    def _drain_pins(self) -> None:
        vcd, cycles, levels = self.vcd, self._pin_cycles, self._pin_levels
        assert vcd is not None
        chips = len(chips_of(self.model))
        ns_per_cycle = 1e9 / CPU_HZ
        while True:
            n = self._lib.fitl_pin_log_take(self._h, cycles, levels, len(cycles))
            for i in range(n):
                v = levels[i]
                lines = {name: (v >> bit) & 1 for bit, name in enumerate(VCD_DATA)}
                lines.update(rd=(v >> 8) & 1, wr=(v >> 9) & 1, ps=(v >> 10) & 1, rst=(v >> 11) & 1)
                for k in range(chips):
                    lines[cs_name(k)] = (v >> (12 + k)) & 1
                    lines[hi_name(k)] = (v >> (16 + k)) & 1
                vcd.set(cycles[i] * ns_per_cycle, lines)
            if n < len(cycles):
                return

    def run_for(self, seconds: float) -> None:
        self.run_until(self.cycle + max(0, math.ceil(seconds * CPU_HZ)))
        self.sync_model()

    def sync_model(self) -> None:
        """Bring the model up to the AVR's time (the harness only does so at bus cycles)."""
        m = self.model
        tick = self.cycle * m.clock_hz // CPU_HZ
        if tick > m.tick:
            m.advance_to(tick)

    def write(self, data: bytes) -> None:
        if not data:
            return
        buf = (ctypes.c_uint8 * len(data)).from_buffer_copy(data)
        n = self._lib.fitl_write(self._h, buf, len(data))
        if n != len(data):
            raise TransportError(f"simulated UART input queue full after {n} of {len(data)} "
                                 "bytes (the host wrote faster than the firmware reads)")

    def take_output(self) -> bytes:
        n = self._lib.fitl_read(self._h, self._buf, len(self._buf))
        return bytes(self._buf[:n])

    @property
    def bus_cycles(self) -> int:
        return int(self._lib.fitl_bus_cycles(self._h))

    def peek(self, address: int) -> int:
        """A byte of the AVR's data space (registers, I/O, RAM): for tests and profiling."""
        return int(self._lib.fitl_peek(self._h, address))

    def memory(self, which: str) -> bytes:
        """A copy of the AVR's ``data`` space, ``flash`` or ``eeprom``: for the tests that a
        reused AVR is as a new one."""
        index = ("data", "flash", "eeprom").index(which)
        buf = (ctypes.c_uint8 * 65536)()
        n = self._lib.fitl_memory(self._h, index, buf, len(buf))
        return bytes(buf[:n])

    def poke(self, which: str, address: int, value: int) -> None:
        """Change a byte of the AVR's ``data`` space, ``flash`` or ``eeprom``, as a firmware that
        wrote them would: for the same tests."""
        if self._lib.fitl_poke(self._h, ("data", "flash", "eeprom").index(which), address, value):
            raise ValueError(f"{which} address {address:#x} is outside the AVR's {which}")

    def irq_state(self) -> list[tuple[int, int]]:
        """(level, flags) of each of simavr's IRQs, in the order simavr made them: for the same
        tests."""
        buf = (ctypes.c_uint32 * 8192)()
        n = self._lib.fitl_irq_state(self._h, buf, len(buf))
        return [(buf[2 * i], buf[2 * i + 1]) for i in range(min(n, len(buf) // 2))]

    def link_counters(self) -> LinkCounters | None:
        """The firmware's own link counters (frames, bad frames, programs run, cache hits), read
        from its RAM; None when ``avr-nm`` is missing or ``link_t`` changed its layout."""
        address = _link_address(self.firmware)
        return None if address is None else LinkCounters(self, address)

    @property
    def pc(self) -> int:
        """The AVR's program counter (byte address), for sampling profiles."""
        return int(self._lib.fitl_pc(self._h))

    def uart_counts(self) -> tuple[int, int, int]:
        """(bytes raised into the simulated UART, XON events, XOFF events)."""
        out = (ctypes.c_uint64 * 3)()
        self._lib.fitl_uart_counts(self._h, out)
        return int(out[0]), int(out[1]), int(out[2])

    def set_access_cycles(self, cycles: int) -> None:
        """The chip's read access time (plus the AVR's input synchroniser) in AVR cycles; the
        default 4 is the datasheet's 180 ns rounded up plus one."""
        self._lib.fitl_set_access_cycles(self._h, cycles)

    def close(self) -> None:
        """End the session; the AVR waits in ``IDLE_AVRS`` for the next open of this image."""
        self._close(keep=True)

    def _close(self, keep: bool) -> None:
        if self._h:
            if self.vcd is not None:
                self._drain_pins()
                self.vcd.close(self.cycle * 1e9 / CPU_HZ)
            h, self._h = self._h, None
            if keep:
                IDLE_AVRS.give(self._key, h)
            else:
                self._lib.fitl_free(h)

    def __del__(self) -> None:  # pragma: no cover - best effort
        # a sim never closed is found by the garbage collector (its callback holds it in a
        # cycle), which runs at any allocation, also inside IDLE_AVRS's lock: freed, not kept
        try:
            self._close(keep=False)
        except Exception:  # noqa: BLE001 - at interpreter exit anything may be gone already
            pass


class AvrClock(Clock):
    """The AVR's simulated time; ``sleep`` runs the firmware (and the chip) forward."""

    def __init__(self, sim: AvrSim) -> None:
        self.sim = sim

    def now(self) -> float:
        return self.sim.now

    def sleep(self, seconds: float) -> None:
        self.sim.run_for(seconds)


class AvrPipe:
    """A :class:`~lm629_host.bridge.protocol.Pipe` to the firmware's UART in simavr."""

    def __init__(self, sim: AvrSim) -> None:
        self.sim = sim
        self.model = sim.model
        self.clock = AvrClock(sim)
        self.closed = False

    def write(self, data: bytes) -> None:
        self.sim.write(bytes(data))

    def set_baud(self, baud: int) -> None:
        """Nothing to do: simavr's UART runs at the rate the firmware sets in UBRR, for the
        bytes the host raises into it too (a failed switch cannot be simulated here)."""

    def read(self, timeout_s: float) -> bytes:
        sim = self.sim
        out = sim.take_output()
        if out:
            return out
        sim.run_until(sim.cycle + max(1, math.ceil(timeout_s * CPU_HZ)), frames=True)
        sim.sync_model()
        return sim.take_output()

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self.sim.close()


#: ``link_t`` of firmware_bridge/link.h on the AVR: 15 bytes of state, then four 16-bit
#: counters (frames, bad_frames, runs, cache_hits, little-endian), 6 bytes of the RUN_SHORT
#: check, the programs kept for RUN_CODE (3 bytes and CODE_BYTES each), the three buffers, then
#: PROFILE's schedule (4 bytes, two 16-bit and four 32-bit fields, 6 bytes a piece)
_LINK_COUNTERS_AT = 15
_LINK_T_SIZE = (15 + 4 * 2 + 6 + CODE_SLOTS * (3 + CODE_BYTES) + 252 + 250 + 252
                + 4 + 2 * 2 + 4 * 4 + 6 * PROFILE_MAX_SCHEDULE)
_link_addresses: dict[Path, int | None] = {}


def _link_address(firmware: Path) -> int | None:
    """RAM address of the firmware's ``link`` (from ``avr-nm -S``), None if it cannot be
    trusted (no avr-nm, no symbol, or a size that is not the layout above)."""
    if firmware not in _link_addresses:
        found = None
        try:
            out = subprocess.run(["avr-nm", "-S", str(firmware)], capture_output=True,
                                 text=True, check=True).stdout
        except (OSError, subprocess.CalledProcessError):
            out = ""
        for line in out.splitlines():
            parts = line.split()
            # a static of main.c: link-time optimisation may rename it link.lto_priv.N
            name = parts[3].split(".", 1)[0] if len(parts) == 4 else ""
            if name == "link" and int(parts[1], 16) == _LINK_T_SIZE:
                found = int(parts[0], 16) & 0xFFFF  # data space: 0x800000 + RAM address
        _link_addresses[firmware] = found
    return _link_addresses[firmware]


class LinkCounters:
    """A live view of the firmware's link counters, counted from the last :meth:`reset` (the
    AVR's 16-bit counters wrap; fine between two reads less than 65536 apart)."""

    NAMES = ("frames", "bad_frames", "runs", "cache_hits")

    def __init__(self, sim: AvrSim, address: int) -> None:
        self._sim, self._address = sim, address
        self._base = self._raw()

    def _raw(self) -> tuple[int, ...]:
        peek, a = self._sim.peek, self._address + _LINK_COUNTERS_AT
        return tuple(peek(a + 2 * i) | peek(a + 2 * i + 1) << 8 for i in range(4))

    def reset(self) -> None:
        self._base = self._raw()

    def __getattr__(self, name: str) -> int:
        if name not in LinkCounters.NAMES:
            raise AttributeError(name)
        i = LinkCounters.NAMES.index(name)
        return (self._raw()[i] - self._base[i]) & 0xFFFF


__all__ = ["AvrSim", "LinkCounters", "AvrPipe", "AvrClock", "CPU_HZ"]
