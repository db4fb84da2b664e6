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

An AVR outlives its :class:`AvrSim`: a closed sim's waits in :data:`IDLE_AVRS` and the next
open of the same image powers it on again (``fitl_restart``), as new in every way the firmware
or a test can see; simavr 1.6 leaks part of every AVR it makes and frees (:class:`_IdleAvrs`).

Several chips: ``model`` may be a :class:`~lm629_host.sim.model.ChipBus`; the harness names the
chip whose /CS was low with each cycle (the firmware's chip-select pins, from the pin map) and
the bus routes the strobe to it; /RST reaches all of them; every chip's HI goes back to its pin.
"""

from __future__ import annotations

import ctypes
import math
import shutil
import subprocess
import sys
import threading
from pathlib import Path

from lm629_host.bridge.protocol.constants import CODE_BYTES, CODE_SLOTS, PROFILE_MAX_SCHEDULE
from lm629_host.clock import Clock
from lm629_host.errors import ProtocolViolation, TransportError
from lm629_host.sim.wiring import Miswiring
from lm629_host.sim.model import ChipBus, ChipModel, chips_of
from lm629_host.sim.vcd import DATA as VCD_DATA
from lm629_host.sim.vcd import BusVcd, cs_name, hi_name

ROOT = Path(__file__).resolve().parents[2]
FIRMWARE_DIR = ROOT / "firmware_bridge"
BUILD_DIR = FIRMWARE_DIR / "build"
LIBRARY = BUILD_DIR / "libfitl.so"
#: the ATmega328P's clock on an Uno / Nano
CPU_HZ = 16_000_000
DEFAULT_BAUD = 115200
#: baud rates the Makefile builds a firmware image for
BUILT_BAUDS = (115200, 1_000_000)

# bus cycle kinds (fitl.c)
STATUS, COMMAND, WRITE, READ, RESET = range(5)

_CALLBACK = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_uint64)


class HarnessError(TransportError):
    """The simulated bridge cannot run (harness not built, firmware missing or crashed)."""


def firmware_path(baud: int = DEFAULT_BAUD) -> Path:
    """The firmware image ``make -C firmware_bridge`` builds for ``baud``."""
    if baud == DEFAULT_BAUD:
        return BUILD_DIR / "lm629_bridge.elf"
    return BUILD_DIR / f"lm629_bridge_{baud}.elf"


#: ELF's e_machine of an AVR image (the ELF specification's EM_AVR)
EM_AVR = 83


def check_firmware(path: Path) -> None:
    """Refuse anything simavr should not be handed (ValueError naming the file and why),
    before it starts: libsimavr's loader spins at 100 % CPU on some files that are not ELF
    images, deaf to Ctrl-C.  An AVR image is a 32-bit little-endian ELF for machine EM_AVR."""
    advice = ("give the .elf that `make -C firmware_bridge` builds "
              f"({firmware_path().relative_to(ROOT)}), or leave firmware= out")
    try:
        with open(path, "rb") as f:
            head = f.read(20)
    except FileNotFoundError:
        raise ValueError(f"firmware={path}: not found; {advice}") from None
    except OSError as exc:
        raise ValueError(f"firmware={path}: cannot read it ({exc.strerror}); {advice}") from None
    if head[:1] == b":":
        why = "an Intel HEX file: that is for flashing a board (lm629 bridge flash); simavr runs the ELF"
    elif head[:4] != b"\x7fELF":
        why = "not an ELF image"
    elif len(head) < 20 or head[4] != 1 or head[5] != 1:
        why = "an ELF image, but not a 32-bit little-endian one as an AVR's is"
    elif int.from_bytes(head[18:20], "little") != EM_AVR:
        why = f"an ELF image for machine {int.from_bytes(head[18:20], 'little')}, not the AVR ({EM_AVR})"
    else:
        return
    raise ValueError(f"firmware={path}: {why}; {advice}")


_lib: ctypes.CDLL | None = None
_built = False

#: Debian packages the firmware and the harness need (``.ci/run`` installs them)
PACKAGES = "gcc-avr avr-libc binutils-avr simavr libsimavr-dev libelf-dev"


def toolchain_missing() -> list[str]:
    """The build tools not found on PATH or in /usr/include (empty when all are there)."""
    missing = [t for t in ("make", "avr-gcc", "avr-objcopy", "avr-size", "cc") if not shutil.which(t)]
    if not Path("/usr/include/simavr/sim_avr.h").exists():
        missing.append("libsimavr-dev")
    return missing


def ensure_built() -> None:
    """Run ``make -C firmware_bridge firmware harness`` once per process (incremental: a few
    milliseconds when nothing changed), so that ``sim+avr://`` runs the firmware of this source
    tree from a fresh clone too.  Without the toolchain, images built earlier are used."""
    global _built
    if _built:
        return
    if not FIRMWARE_DIR.is_dir():
        raise HarnessError(f"sim+avr:// builds the bridge firmware from its sources, "
                           f"{FIRMWARE_DIR}, which only a checkout of lm629-host has (an "
                           "installed package carries the image, not the sources): run it from "
                           "a checkout, or use sim+emu:// (the Python bridge)")
    if toolchain_missing():
        if LIBRARY.exists() and firmware_path().exists():
            _built = True
            return
        raise HarnessError(f"the simavr harness and firmware are not built and the toolchain is "
                           f"missing ({', '.join(toolchain_missing())}): apt-get install {PACKAGES}, "
                           "then `make -C firmware_bridge`")
    cmd = ["make", "-s", "-C", str(FIRMWARE_DIR), "firmware", "harness"]
    # `make -q`: exit 0 when everything is up to date; otherwise say once what is built (a cold
    # build takes a few seconds, which should not pass in silence)
    files = ["build/lm629_bridge.hex", "build/lm629_bridge_1000000.hex", "build/libfitl.so"]
    if subprocess.run(["make", "-q", "-C", str(FIRMWARE_DIR), *files],
                      capture_output=True).returncode:
        print(f"sim+avr://: building the bridge firmware and the simavr harness "
              f"(make -C {FIRMWARE_DIR} firmware harness)", file=sys.stderr, flush=True)
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode:
        raise HarnessError(f"`make -C {FIRMWARE_DIR} firmware harness` failed:\n"
                           f"{(r.stdout + r.stderr)[-2000:]}")
    _built = True


def load_library(path: Path = LIBRARY) -> ctypes.CDLL:
    """The harness library (loaded once)."""
    global _lib
    if _lib is not None:
        return _lib
    if path == LIBRARY:
        ensure_built()
    if not path.exists():
        raise HarnessError(f"the simavr harness {path} is not built: run `make -C firmware_bridge` "
                           "(needs gcc-avr, avr-libc, binutils-avr, simavr, libsimavr-dev, "
                           "libelf-dev)")
    lib = ctypes.CDLL(str(path))
    p, u8p = ctypes.c_void_p, ctypes.POINTER(ctypes.c_uint8)
    lib.fitl_new.argtypes, lib.fitl_new.restype = [ctypes.c_char_p, _CALLBACK], p
    lib.fitl_error.argtypes, lib.fitl_error.restype = [], ctypes.c_char_p
    lib.fitl_free.argtypes, lib.fitl_free.restype = [p], None
    lib.fitl_restart.argtypes, lib.fitl_restart.restype = [p, _CALLBACK], ctypes.c_int
    lib.fitl_memory.argtypes = [p, ctypes.c_int, u8p, ctypes.c_uint32]
    lib.fitl_memory.restype = ctypes.c_uint32
    lib.fitl_poke.argtypes = [p, ctypes.c_int, ctypes.c_uint32, ctypes.c_uint8]
    lib.fitl_poke.restype = ctypes.c_int
    lib.fitl_irq_state.argtypes = [p, ctypes.POINTER(ctypes.c_uint32), ctypes.c_uint32]
    lib.fitl_irq_state.restype = ctypes.c_uint32
    lib.fitl_write.argtypes, lib.fitl_write.restype = [p, u8p, ctypes.c_uint32], ctypes.c_int
    lib.fitl_run.argtypes, lib.fitl_run.restype = [p, ctypes.c_uint64, ctypes.c_int], ctypes.c_int
    lib.fitl_read.argtypes, lib.fitl_read.restype = [p, u8p, ctypes.c_uint32], ctypes.c_uint32
    lib.fitl_cycle.argtypes, lib.fitl_cycle.restype = [p], ctypes.c_uint64
    lib.fitl_pending_input.argtypes, lib.fitl_pending_input.restype = [p], ctypes.c_uint32
    lib.fitl_bus_cycles.argtypes, lib.fitl_bus_cycles.restype = [p], ctypes.c_uint64
    lib.fitl_set_access_cycles.argtypes, lib.fitl_set_access_cycles.restype = [p, ctypes.c_int], None
    lib.fitl_peek.argtypes, lib.fitl_peek.restype = [p, ctypes.c_uint16], ctypes.c_uint8
    lib.fitl_pc.argtypes, lib.fitl_pc.restype = [p], ctypes.c_uint32
    lib.fitl_uart_counts.argtypes = [p, ctypes.POINTER(ctypes.c_uint64)]
    lib.fitl_uart_counts.restype = None
    lib.fitl_violations.argtypes = [p, ctypes.c_char_p, ctypes.c_uint32]
    lib.fitl_violations.restype = ctypes.c_uint32
    lib.fitl_pin_log.argtypes, lib.fitl_pin_log.restype = [p, ctypes.c_int], None
    lib.fitl_pin_log_take.argtypes = [p, ctypes.POINTER(ctypes.c_uint64),
                                      ctypes.POINTER(ctypes.c_uint32), ctypes.c_uint32]
    lib.fitl_pin_log_take.restype = ctypes.c_uint32
    _lib = lib
    return lib


def _image_key(firmware: Path) -> tuple[object, ...]:
    """What makes two opens run the same AVR: the same image file, unchanged since (a rebuilt
    or replaced file is another key).  The MCU (ATmega328P) and its clock (``CPU_HZ``) are the
    harness's own, the same for every AVR it makes."""
    st = firmware.stat()
    return (str(firmware.resolve()), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


class _IdleAvrs:
    """Simulated AVRs of closed :class:`AvrSim` s, kept to be powered on again by the next open
    of the same image (``fitl_restart``: RAM, flash, EEPROM, every IRQ's level, the cycle count,
    the peripherals and the harness's state as a new AVR's), so that an open/close does not
    make and free a simavr AVR each time: simavr 1.6 never frees part of what ``avr_init``
    makes (about 5 KB of IRQ names and pools an AVR, valgrind), and 300 opens grew a process by
    about 1.2 MB.  Freeing those from the harness would walk simavr's private lists; a reset is
    what simavr does itself for a watchdog reset.

    An AVR in use is never here: two sims open at once have two AVRs.  At most ``size`` wait
    here (the oldest is freed first); at interpreter exit they go with the process."""

    def __init__(self, size: int) -> None:
        self.size = size
        self._lock = threading.Lock()
        self._idle: list[tuple[tuple[object, ...], int]] = []

    def take(self, key: tuple[object, ...]) -> int | None:
        """An idle AVR of ``key`` (removed from here), or None."""
        with self._lock:
            for i in range(len(self._idle) - 1, -1, -1):
                if self._idle[i][0] == key:
                    return self._idle.pop(i)[1]
        return None

    def give(self, key: tuple[object, ...], handle: int) -> None:
        """Keep a closed sim's AVR for the next open of ``key``, freeing the oldest beyond
        ``size``."""
        with self._lock:
            self._idle.append((key, handle))
            spill = self._idle[:-self.size] if self.size else self._idle[:]
            del self._idle[:len(spill)]
        for _, h in spill:
            load_library().fitl_free(h)

    def clear(self) -> None:
        """Free every idle AVR (the next open makes a new one)."""
        with self._lock:
            idle, self._idle = self._idle, []
        for _, h in idle:
            load_library().fitl_free(h)

    def __len__(self) -> int:
        with self._lock:
            return len(self._idle)


#: the idle AVRs of this process (a few: one per image is what a loop of opens needs, a board
#: test opening several at once gets several back)
IDLE_AVRS = _IdleAvrs(4)


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
        self._cb = _CALLBACK(self._on_bus)  # referenced for as long as the simulation lives
        self._key = _image_key(self.firmware)
        self._h = IDLE_AVRS.take(self._key)
        if self._h and self._lib.fitl_restart(self._h, self._cb):
            self._lib.fitl_free(self._h)  # it did not boot again: a new one says why, if so
            self._h = None
        #: this sim's AVR was a closed sim's, powered on again (:class:`_IdleAvrs`)
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
        """End the session; the AVR waits in :data:`IDLE_AVRS` for the next open of this image."""
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


__all__ = ["AvrSim", "LinkCounters", "check_firmware", "EM_AVR",
           "AvrPipe", "AvrClock", "HarnessError", "firmware_path", "load_library",
           "CPU_HZ", "BUILT_BAUDS", "ensure_built", "toolchain_missing", "PACKAGES"]
