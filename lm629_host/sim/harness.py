"""What ``sim+avr://`` runs, before it runs: the bridge firmware image and the simavr harness.

``make -C firmware_bridge`` builds both from this checkout's sources (:func:`ensure_built`,
once per process); :func:`check_firmware` refuses a file simavr should not be handed;
:func:`load_library` loads the harness (``build/libfitl.so``) through ctypes.  The running
simulation is :mod:`lm629_host.sim.avr`.

An AVR the harness made outlives its :class:`~lm629_host.sim.avr.AvrSim`: a closed sim's
waits in :data:`IDLE_AVRS` and the next open of the same image (:func:`image_key`) powers it on
again (``fitl_restart``); simavr 1.6 leaks part of every AVR it makes and frees
(:class:`_IdleAvrs`).
"""

from __future__ import annotations

import ctypes
import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path

from lm629_host.errors import TransportError

ROOT = Path(__file__).resolve().parents[2]
FIRMWARE_DIR = ROOT / "firmware_bridge"
BUILD_DIR = FIRMWARE_DIR / "build"
LIBRARY = BUILD_DIR / "libfitl.so"
DEFAULT_BAUD = 115200
#: baud rates the Makefile builds a firmware image for
BUILT_BAUDS = (115200, 1_000_000)

#: the harness's bus-cycle callback: (kind, value, AVR cycle) -> the byte read, HI in bit 8 up
BUS_CALLBACK = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_uint64)


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
    # each image and the harness are one compiler run of their own: built side by side
    cmd = ["make", "-s", f"-j{len(os.sched_getaffinity(0))}", "-C", str(FIRMWARE_DIR),
           "firmware", "harness"]
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
    lib.fitl_new.argtypes, lib.fitl_new.restype = [ctypes.c_char_p, BUS_CALLBACK], p
    lib.fitl_error.argtypes, lib.fitl_error.restype = [], ctypes.c_char_p
    lib.fitl_free.argtypes, lib.fitl_free.restype = [p], None
    lib.fitl_restart.argtypes, lib.fitl_restart.restype = [p, BUS_CALLBACK], ctypes.c_int
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


def image_key(firmware: Path) -> tuple[object, ...]:
    """What makes two opens run the same AVR: the same image file, unchanged since (a rebuilt
    or replaced file is another key).  The MCU (ATmega328P) and its clock (16 MHz) are the
    harness's own, the same for every AVR it makes."""
    st = firmware.stat()
    return (str(firmware.resolve()), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


class _IdleAvrs:
    """Simulated AVRs of closed :class:`~lm629_host.sim.avr.AvrSim` s, kept to be powered on again by the next open
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

__all__ = ["HarnessError", "check_firmware", "EM_AVR", "firmware_path", "load_library",
           "BUILT_BAUDS", "DEFAULT_BAUD", "ensure_built", "toolchain_missing", "PACKAGES",
           "IDLE_AVRS", "image_key", "BUS_CALLBACK", "FIRMWARE_DIR", "BUILD_DIR", "LIBRARY"]
