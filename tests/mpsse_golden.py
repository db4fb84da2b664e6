"""The MPSSE streams of representative programs, as the FT232H transport compiles them.

Run as a script to write ``tests/data/mpsse_streams.json`` (``python tests/mpsse_golden.py``).
The file checked in was written by the code *before* the compiler moved out of
``transports/ftdi.py`` into ``transports/mpsse.py`` (branch ftdi, commit 2728094), so that
``tests/transports/test_mpsse_streams.py`` proves the move changed no byte; the two calibrated sessions
with a busy repeat (``sim+ftdi://`` and ``?axes=2``) are written by the code that doubles the
wait after a repeat, the rest as the move left them.  Two levels are captured:

* the pure compiler: each program below through ``StreamCompiler.compile`` with the
  arguments the transport uses (the 1 KiB cut, owed leads, per-chip waits, skips, command
  cost), every stream cut of :func:`streams_of`;
* the whole transport on the emulated FT232H: every bulk OUT payload of a session of typed
  commands (open, calibration, busy repeats after ``stretch_busy``, polls), as bytes.

Short records are stored whole (bytes as hex); longer ones as the SHA-256 of their JSON.
"""

from __future__ import annotations

import hashlib
import json
import pathlib
import sys
from collections.abc import Callable
from typing import Any

import lm629_host
from lm629_host import Cmd, Program

OUT = pathlib.Path(__file__).with_name("data") / "mpsse_streams.json"


def programs() -> dict[str, Program]:
    """Every operation kind, each stream cut, both chips."""
    p: dict[str, Program] = {}
    p["udf"] = Program().command(Cmd.UDF)
    p["ltrj_stt"] = (Program().command(Cmd.LTRJ).write(0x2A).write32(0x1234).write32(0x56789)
                     .write32(-1000 & 0xFFFFFFFF).status().command(Cmd.STT).sync())
    p["lfil_udf"] = (Program().command(Cmd.LFIL).write(0x000F).write(20).write(1).write(100)
                     .write(500).command(Cmd.UDF))
    p["rdrp"] = Program().command(Cmd.RDRP).read(2)
    p["snapshot"] = (Program().status().command(Cmd.RDRP).read(2).command(Cmd.RDDP).read(2)
                     .command(Cmd.RDRV).read(1).command(Cmd.RDSIGS).read(1))
    p["reset"] = Program().reset().wait(1500).status().command(Cmd.RSTI).write(0).status()
    p["soft_reset"] = Program().command(Cmd.RESET).wait(1500).status()
    p["two_axes_start"] = (Program().command(Cmd.LTRJ).write(0x2A).write32(1).write32(2)
                           .write32(3).select(1).command(Cmd.LTRJ).write(0x2A).write32(4)
                           .write32(5).write32(6).select(0).command(Cmd.STT).select(1)
                           .command(Cmd.STT).select(0).sync())
    p["raw_unknown"] = Program().command(Cmd.MSKI).write(0).command(0x55).status()
    p["rdrp_550"] = Program()
    for _ in range(550):
        p["rdrp_550"].command(Cmd.RDRP).read(2)
    return p


def _enc(data: bytes) -> Any:
    return data.hex()


def _small(record: Any) -> Any:
    """``record`` itself when short, else the SHA-256 of its canonical JSON (and its size)."""
    text = json.dumps(record, sort_keys=True)
    if len(text) <= 1500:
        return record
    return {"sha256": hashlib.sha256(text.encode()).hexdigest(), "json_chars": len(text)}


def compiled() -> dict[str, Any]:
    """Each program, cut as the transport cuts it, through the compiler in several setups."""
    try:
        from lm629_host.transports.ftdi_busy import COMMAND_S
    except ImportError:  # commit 2728094, which wrote the golden file, has it in ftdi.py
        from lm629_host.transports.ftdi import COMMAND_S  # type: ignore[attr-defined, no-redef]  # there at 2728094
    try:
        from lm629_host.transports.mpsse import StreamCompiler, chips_of_units, streams_of
    except ImportError:  # commit 2728094, which wrote the golden file, has them in ftdi.py
        from lm629_host.transports.ftdi import (  # type: ignore[attr-defined, no-redef]  # there at 2728094
            StreamCompiler, chips_of_units, streams_of)
    from lm629_host.wiring.ft232h import FIFO_BYTES
    setups: dict[str, Callable[[], Any]] = {
        "fixed100": lambda: StreamCompiler(6e6, 100e-6),
        "measured22": lambda: StreamCompiler(6e6, 22e-6, COMMAND_S),
        "slow1MHz": lambda: StreamCompiler(1e6, 100e-6),
    }
    out: dict[str, Any] = {}
    for sname, make in setups.items():
        for pname, prog in programs().items():
            ops = prog.ops
            chip_at = chips_of_units(ops)
            for lead in (0.0, {0: 7e-6, 1: 40e-6}):
                c = make()
                streams = []
                for units in streams_of(ops):
                    pos, end = units[0][0], units[-1][1]
                    skip: set[int] = set()
                    if pname == "two_axes_start" and units[0][0] == 0:
                        skip = {k for k in range(8, 16)}  # a repeat's units already taken
                    while pos < end:
                        s = c.compile(ops[pos:end], pos, lead, max_bytes=FIFO_BYTES,
                                      chip=chip_at[pos - 1] if pos else 0, skip=skip)
                        streams.append(_small({"data": _enc(bytes(s.data)),
                                        "slots": [[sl.kind, sl.op] for sl in s.slots],
                                        "events": [list(e) for e in s.events],
                                        "delay_ns": round(s.delay_s * 1e9, 3),
                                        "strobes": s.strobes, "end": c.end,
                                        "owed_after": {str(k): round(v * 1e9, 3)
                                                       for k, v in sorted(c.owed_after.items())}}))
                        pos = c.end
                key = f"{sname}/{pname}/lead={'dict' if isinstance(lead, dict) else lead}"
                out[key] = streams
    return out


def transported() -> dict[str, Any]:
    """Every bulk OUT of typed-command sessions on the emulated FT232H."""
    out: dict[str, Any] = {}
    for url in ("sim+ftdi://", "sim+ftdi://?busy_us=100", "sim+ftdi://?axes=2"):
        with lm629_host.open(url) as chip:
            dev = chip.transport.device  # type: ignore[attr-defined]  # sim+ftdi:// only
            sent: list[bytes] = []
            orig = dev.bulk_out

            def rec(data: bytes, _orig: Callable[[bytes], int] = orig,
                    _sent: list[bytes] = sent) -> int:
                _sent.append(bytes(data))
                return _orig(data)

            dev.bulk_out = rec  # type: ignore[method-assign]  # a recording wrapper
            chip.reset()
            chip.load_filter(kp=20, ki=1, kd=100, il=500)
            chip.load_trajectory(acceleration=0x1234, velocity=0x56789, position=-1000,
                                 start=True)
            chip.read_real_position()
            chip.snapshot()
            dev.chip_pins.stretch_busy(1, 300e-6, skip=2)  # a busy repeat and polls
            chip.load_trajectory(acceleration=0x1234, velocity=0x56789, position=4000)
            chip.read_status()
            out[url] = [_small(_enc(b)) for b in sent]
    return out


def main() -> None:
    doc = {"compiled": compiled(), "transported": transported()}
    OUT.write_text(json.dumps(doc, indent=0, sort_keys=True) + "\n")
    print(f"wrote {OUT} ({OUT.stat().st_size} bytes)", file=sys.stderr)


if __name__ == "__main__":
    main()
