#!/usr/bin/env python3
"""Every figure of the performance table (docs/performance.md), measured now, before and after.

    python3 tools/bench_all.py                  # measure and print the table
    python3 tools/bench_all.py --write-readme   # ... and write it into docs/performance.md
    python3 tools/bench_all.py --baseline REF   # "before" = another commit (default below)
    python3 tools/bench_all.py --write-readme --fresh-clone   # also a fresh clone's test run
    python3 tools/bench_all.py --write-readme --only-usb      # only the per-adapter table
    python3 tools/bench_all.py --write-readme --only-failsafe # only the failsafe's table
    python3 tools/bench_all.py --write-readme --only-idle     # only the idle simulated time

"Before" is measured, not remembered: the baseline commit's ``lm629_host`` is unpacked from git
into a temporary directory (its C sample loop built there) and the same probes run against it
in a subprocess, on the same machine at the same time as "after".  Figures that have no
"before" (the transports the issue only asked to measure) show "-".  Wall-clock figures are
medians of 3 on a shared 2-core machine (+/- 30 %); simulated figures are exact.

Also runs every other benchmark in tools/ briefly, so that one that no longer runs shows here.
"""

from __future__ import annotations

import argparse
import datetime
import math
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: the link before its CRC table was generated (still made by preprocessor macros)
BASELINE = "26fd81f"
#: the serial link and the FT232H before their compact programs: "before" of their rows
LINK_BASELINE = "7b12192"
#: the FT232H's limits: two 125 us USB microframes + the chip's own time
FTDI_LIMIT_US = {"rdrp": 253.0, "ltrj_stt": 478.0}
#: the FT232H with D0 wired to GPIOL1: the adapter waits on the busy bit (docs/ftdi.md)
FTDI_BUSY_PIN = "sim+ftdi://?busy_pin=gpiol1"
COMMAND = "python3 tools/bench_all.py --write-readme"
BEGIN, END = "<!-- bench_all.py: begin -->", "<!-- bench_all.py: end -->"
USB_BEGIN, USB_END = "<!-- bench_all.py usb: begin -->", "<!-- bench_all.py usb: end -->"
#: the README's summary of the per-adapter table (generated too)
SUMMARY_BEGIN = "<!-- bench_all.py usb summary: begin -->"
SUMMARY_END = "<!-- bench_all.py usb summary: end -->"
README = ROOT / "README.md"
IDLE_BEGIN, IDLE_END = "<!-- bench_all.py idle: begin -->", "<!-- bench_all.py idle: end -->"
#: "before" of the idle rows: the link before its simulated sleeps were exact
IDLE_BASELINE = "c351da8"
#: the idle probe's far ends, the failsafe armed as the URL leaves it (0.5 s)
IDLE_URLS = ("sim+avr://", "sim+avr://?usb=uno", "sim+emu://")
FAILSAFE_BEGIN = "<!-- bench_all.py failsafe: begin -->"
FAILSAFE_END = "<!-- bench_all.py failsafe: end -->"


# ------------------------------------------------------------------ probes (run in a subprocess)
def _per_call_us(fn, n: int) -> float:
    fn()
    t0 = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - t0) / n * 1e6


def _median3(fn) -> float:
    return statistics.median(fn() for _ in range(3))


def _chip(url: str = "sim://"):
    import lm629_host

    chip = lm629_host.open(url)
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    return chip


def _update_due(chip) -> None:
    """Wait (on the chip's clock) until the next trajectory update may go out: the library
    holds an STT 10 ms after the last (AN-706 4.6.2), which is the rule's time, not the
    exchange's; a "before" without the rule has nothing to wait for."""
    due = getattr(chip, "update_due", None)
    if due is not None:
        chip.clock.sleep(due())


def _per_command(chip, fn, n: int) -> dict:
    """Counters and simulated time per command (exact: what must not change)."""
    s = chip.transport.stats
    s.reset()
    t0 = chip.clock.now()
    for _ in range(n):
        fn()
    return {"bus_cycles": s.bus_cycles / n, "busy_polls": s.busy_polls / n,
            "sim_us": (chip.clock.now() - t0) / n * 1e6}


def probe_cost() -> dict:
    """Host cost and waiting speed, one measurement each: main() runs this probe on the
    baseline and on this tree in turn, three times, and takes the medians (the machine's load
    drifts: interleaving keeps "before" and "after" under the same load)."""
    from lm629_host import Status
    from lm629_host.bus.opcodes import Cmd

    out: dict = {}
    chip = _chip()
    out["rdrp_us"] = _per_call_us(chip.read_real_position, 3000)
    pos = [1000]

    def ltrj_stt() -> None:  # as tools/bench_core.py
        pos[0] = -pos[0]
        chip.run(chip.trajectory_program(acceleration=100, velocity=65536, position=pos[0])
                 .command(Cmd.STT))

    out["ltrj_stt_us"] = _per_call_us(ltrj_stt, 1000)
    # a move of ~21.7 s: 2 counts/sample after a 1.7 s ramp
    c = _chip()
    c.load_trajectory(acceleration=20, velocity=0x20000, position=156240)
    c.start()
    t0, w0 = c.clock.now(), time.perf_counter()
    c.wait_for(Status.TRAJECTORY_COMPLETE, timeout=60)
    out["wait_x"] = (c.clock.now() - t0) / (time.perf_counter() - w0)
    return out


def probe_core() -> dict:
    """The exact figures that exist before and after (the API they use is the same)."""
    import tracemalloc

    import lm629_host
    from lm629_host.bus.opcodes import Cmd

    out: dict = {"module": lm629_host.__file__}
    chip = _chip()
    out["rdrp_counts"] = _per_command(chip, chip.read_real_position, 1000)
    pos = [1000]

    def ltrj_stt() -> None:
        pos[0] = -pos[0]
        chip.run(chip.trajectory_program(acceleration=100, velocity=65536, position=pos[0])
                 .command(Cmd.STT))

    out["ltrj_stt_counts"] = _per_command(chip, ltrj_stt, 1000)
    out["rdrp_bytecodes"] = _bytecodes(chip.read_real_position)
    out["ltrj_stt_bytecodes"] = _bytecodes(ltrj_stt)
    out["wait_emu"] = _link_wait("sim+emu://?baud=115200")

    chip = lm629_host.open("sim://?record=1")
    chip.reset()
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    for i in range(100_000):
        chip.run(chip.program().command(Cmd.SBPA).write32(i))
    out["record_mb"] = (tracemalloc.get_traced_memory()[0] - before) / 1e6
    tracemalloc.stop()
    return out


def _bytecodes(fn, n: int = 50) -> float:
    """Python bytecode instructions per call of ``fn`` (exact, whatever the machine's load:
    the host cost's own figure beside the noisy microseconds; work done in C, the sample loop
    and builtins, counts as one instruction)."""
    import sys

    count = [0]

    def tracer(frame, event, arg):
        frame.f_trace_opcodes = True
        if event == "opcode":
            count[0] += 1
        return tracer

    for _ in range(5):
        fn()
    sys.settrace(tracer)
    try:
        for _ in range(n):
            fn()
    finally:
        sys.settrace(None)
    return count[0] / n


def _link_wait(url: str, transport=None, seconds: float = 10.0) -> dict:
    """Bytes on the link during a wait of ``seconds`` for a bit that never comes."""
    import lm629_host
    from lm629_host import Status
    from lm629_host.errors import WaitTimeout

    chip = lm629_host.LM629(transport) if transport is not None else lm629_host.open(url)
    chip.reset()
    s = chip.transport.stats
    b0, r0, t0 = s.bytes_in + s.bytes_out, s.round_trips, chip.clock.now()
    try:
        chip.wait_for(Status.INDEX_PULSE, timeout=seconds)
    except WaitTimeout:
        pass
    t = chip.clock.now() - t0
    return {"bps": (s.bytes_in + s.bytes_out - b0) / t, "round_trips": s.round_trips - r0, "s": t}


TRANSPORTS = ("sim+avr://?baud=115200", "sim+avr://?baud=1000000", "sim+ftdi://")


def probe_transports() -> dict:
    """Simulated microseconds per command through the firmware (``sim+avr://``) and the FT232H
    (``sim+ftdi://``), exact; run on this tree and on the link baseline.  Each command follows
    a motor-off stop (no STT refused), as a command in a script would; the first 3 of each
    kind are not counted (a bridge with PROGRAM_CODES keeps a program it has seen twice; an
    FT232H measures the chip's busy time before its first program); ``first`` is RDRP sent
    for the first time (its program not kept yet)."""
    out: dict = {}
    for url in TRANSPORTS:
        out[url] = _timed_commands(url)
    return out


def _timed_commands(url: str) -> dict:
    """RDRP (the first, then the mean of 20) and LTRJ(6)+STT on ``url``, simulated us, and the
    bytes of one RDRP round trip."""
    chip = _chip(url)
    pos = [1000]

    def timed(fn, n: int = 20, warm: int = 3) -> float:
        total = 0.0
        for i in range(warm + n):
            chip.load_trajectory(stop="off", start=True)  # no refused STT
            pos[0] = -pos[0]
            _update_due(chip)
            t0 = chip.clock.now()
            fn()
            if i >= warm:
                total += chip.clock.now() - t0
        return total / n * 1e6

    first = timed(chip.read_real_position, 1, 0)
    out = {
        "first": first,
        "rdrp": timed(chip.read_real_position),
        "ltrj_stt": timed(lambda: chip.load_trajectory(
            acceleration=100, velocity=65536, position=pos[0], start=True)),
    }
    s = chip.transport.stats
    s.reset()
    chip.read_real_position()
    out["bytes"] = s.bytes_out + s.bytes_in
    chip.close()
    return out


#: the links a user can have between the host and the chip (docs/usb.md): name, URL; the
#: serial ones through the compiled firmware (sim+avr://) at 1 Mbaud
USB_LINKS = (
    ("none (the line alone, no USB)", "sim+avr://?fast_baud=1000000"),
    ("Arduino Uno R3 (16U2, `usb=uno`)", "sim+avr://?fast_baud=1000000&usb=uno"),
    ("FTDI FT232R/FT231X, 1 ms latency timer (`usb=ftdi&latency_ms=1`)",
     "sim+avr://?fast_baud=1000000&usb=ftdi&latency_ms=1"),
    ("FTDI, default 16 ms latency timer (`usb=ftdi`)", "sim+avr://?fast_baud=1000000&usb=ftdi"),
    ("native full-speed CDC (ATmega32U4, `usb=cdc`)", "sim+avr://?fast_baud=1000000&usb=cdc"),
    ("FT232H, MPSSE (`sim+ftdi://`)", "sim+ftdi://"),
    ("FT232H, D0 also on GPIOL1 (`sim+ftdi://?busy_pin=gpiol1`)", FTDI_BUSY_PIN),
)
#: the move timed per link: 4000 counts at 4 counts/sample, 2048 / 65536 counts/sample^2
USB_MOVE = {"position": 4000, "velocity": 4 * 65536, "acceleration": 2048}
USB_FILTER = dict(kp=400, kd=2000)  # settles in ~45 ms: the link's share shows


def probe_usb() -> dict:
    """Simulated time per link (exact for a seed): RDRP and LTRJ(6)+STT back to back, a
    4000-count move_to + wait against the profile's own time, and the recording rate (full
    snapshot rows, on the bridge where it records there, else host-polled).  Three runs at
    different phases (usb_seed 0-2, the move started i/3 of a flush tick later) are averaged."""
    import lm629_host
    from lm629_host.chip.recording import sample_program
    from lm629_host.sim.usb import UNO_FLUSH_S

    out: dict = {}
    for _name, base in USB_LINKS:
        runs = []
        for i in range(3):
            url = f"{base}&usb_seed={i}" if "usb=" in base else base
            chip = lm629_host.open(url)
            chip.reset()
            chip.load_filter(**USB_FILTER)
            chip.update_filter()
            clock = chip.clock
            clock.sleep(i * UNO_FLUSH_S / 3)
            for _ in range(3):
                chip.read_real_position()  # the bridge keeps the program (RUN_CODE)
            t0 = clock.now()
            for _ in range(20):
                chip.read_real_position()
            rdrp = (clock.now() - t0) / 20
            ltrj, pos = 0.0, 500
            for k in range(13):
                chip.load_trajectory(stop="off", start=True)  # no refused STT
                pos = -pos
                _update_due(chip)
                t0 = clock.now()
                chip.load_trajectory(acceleration=100, velocity=65536, position=pos,
                                     start=True)
                if k >= 3:
                    ltrj += (clock.now() - t0) / 10
            # recording: full snapshot rows at the highest rate the link carries, on the far
            # side where the transport records there (the bridge's RECORD), else host-polled
            t = chip.transport
            top = t.record_max_rate(sample_program(chip, full=True))
            if t.records_on_far_side and top is not None:
                tr = chip.record(1 / math.floor(top), 0.25, full=True)
                rows, far = (len(tr) - 1) / tr.t[-1], 1.0
            else:
                t0 = clock.now()
                n = 0
                while clock.now() - t0 < 0.25:
                    chip.snapshot()
                    n += 1
                rows, far = n / (clock.now() - t0), 0.0
            chip.close()
            chip = lm629_host.open(url)  # the move on a chip at rest, as a script's first
            chip.reset()
            chip.load_filter(**USB_FILTER)
            chip.update_filter()
            clock = chip.clock
            clock.sleep(i * UNO_FLUSH_S / 3)
            t0 = clock.now()
            move = chip.move_to(USB_MOVE["position"], velocity=USB_MOVE["velocity"],
                                acceleration=USB_MOVE["acceleration"])
            move.wait()
            runs.append({"rdrp": rdrp, "ltrj_stt": ltrj, "move": clock.now() - t0,
                         "profile": move.profile_s(8e6) or 0.0, "rows": rows, "far": far})
            chip.close()
        out[base] = {k: statistics.mean(r[k] for r in runs) for k in runs[0]}
    return out


def _bytecodes_cell(r: dict, before: dict | None = None) -> str:
    """Bytecode instructions per RDRP / LTRJ+STT, with the ratio to ``before`` when both have
    them (a baseline older than the figure has none)."""
    if "rdrp_bytecodes" not in r:
        return "-"
    cell = f"{r['rdrp_bytecodes']:.0f} / {r['ltrj_stt_bytecodes']:.0f}"
    if before is not None and "rdrp_bytecodes" in before:
        cell += (f" ({before['rdrp_bytecodes'] / r['rdrp_bytecodes']:.1f}x / "
                 f"{before['ltrj_stt_bytecodes'] / r['ltrj_stt_bytecodes']:.1f}x fewer)")
    return cell


def render_usb(usb: dict, date: str) -> str:
    """The per-adapter table (docs/performance.md, "Per USB adapter")."""
    from lm629_host.sim.usb import UNO_FLUSH_S

    none = usb[USB_LINKS[0][1]]
    lines = [
        USB_BEGIN,
        f"Measured {date} by `{COMMAND}` (or `--only-usb`), in simulated time: the compiled",
        "firmware in simavr at 1 Mbaud behind each USB model of `lm629_host/sim/usb.py`",
        "(docs/usb.md), and the emulated FT232H. Means of 3 runs at different flush-timer",
        f"phases. The move: `move_to({USB_MOVE['position']}, velocity={USB_MOVE['velocity']}, "
        f"acceleration={USB_MOVE['acceleration']}).wait()` with kp={USB_FILTER['kp']}, "
        f"kd={USB_FILTER['kd']}; its profile takes {none['profile'] * 1e3:.1f} ms.",
        "Recording: full snapshot rows (`chip.record(period, 0.25, full=True)`) at the highest",
        "rate the link carries: sampled and stamped by the bridge (RECORD, firmware 1.3) where",
        "it records, so USB changes only when rows arrive; host-polled (one exchange a row) on",
        "the FT232H.",
        "",
        "| link | RDRP | LTRJ(6)+STT | move_to + wait (over the profile) | recording |",
        "|---|---|---|---|---|",
    ]
    for name, url in USB_LINKS:
        d = usb[url]
        extra = d["move"] - d["profile"]
        more = d["move"] - none["move"]
        vs = "" if url == USB_LINKS[0][1] else f"; {more * 1e3:+.1f} ms vs none" + (
            f" = {more / UNO_FLUSH_S:+.2f} flush ticks" if "usb=uno" in url else "")
        lines.append(f"| {name} | {_us(d['rdrp'])} | {_us(d['ltrj_stt'])} | "
                     f"{d['move'] * 1e3:.1f} ms (+{extra * 1e3:.1f} ms{vs}) | "
                     f"{d['rows']:.0f} rows/s, "
                     f"{'on the bridge' if d['far'] else 'host-polled'} |")
    lines.append(USB_END)
    return "\n".join(lines)


def render_usb_summary(usb: dict) -> str:
    """What an Uno user sees, for the README (from the same figures as the table)."""
    none, uno = usb[USB_LINKS[0][1]], usb[USB_LINKS[1][1]]
    ftdi1, ftdi16, cdc, ft232h, ft232h_pin = (usb[url] for _, url in USB_LINKS[2:])
    return "\n".join([
        SUMMARY_BEGIN,
        "**What USB adds** (simulated, `python3 tools/bench_all.py --write-readme --only-usb`;",
        "the models and their sources: [docs/usb.md](docs/usb.md), the table:",
        "[docs/performance.md](docs/performance.md#per-usb-adapter)). Every command is one",
        "exchange with the bridge, and on an **Arduino Uno R3** each exchange waits for its USB",
        f"chip's 4.096 ms flush tick: a read such as RDRP takes {_us(uno['rdrp'])} (the",
        f"{_us(none['rdrp'])} of the 1 Mbaud line and firmware alone is not what an Uno user",
        f"sees), LTRJ+STT {_us(uno['ltrj_stt'])}, a 4000-count `move_to(...).wait()` "
        f"{uno['move'] * 1e3:.1f} ms",
        f"against {none['move'] * 1e3:.1f} ms without USB (profile "
        f"{none['profile'] * 1e3:.1f} ms; `move_to` is one exchange and the bridge sees the",
        f"move's end), and traces (`chip.record`, `lm629 watch`, `step`) are sampled by the "
        f"bridge: {uno['rows']:.0f} full rows/s,",
        "each stamped with the bridge's clock, however the flush tick bunches them.",
        f"An FTDI adapter takes {_us(ftdi1['rdrp'])} per exchange with its latency timer at "
        f"1 ms (the serial",
        f"transport asks the driver for that) and {_us(ftdi16['rdrp'])} at its default 16 ms; "
        f"a native USB board",
        f"(ATmega32U4) {_us(cdc['rdrp'])}; the FT232H {_us(ft232h['rdrp'])} (LTRJ+STT "
        f"{_us(ft232h['ltrj_stt'])},",
        f"{_us(ft232h_pin['ltrj_stt'])} in one exchange with D0 also on GPIOL1, "
        "`busy_pin=gpiol1`).",
        SUMMARY_END,
    ])


def _us(seconds: float) -> str:
    return f"{seconds * 1e6:.0f} us" if seconds < 1e-3 else f"{seconds * 1e3:.2f} ms"


def replace_block(text: str, begin: str, end: str, block: str) -> str:
    """``text`` with everything from the marker ``begin`` to ``end`` replaced by ``block``
    (which carries the markers again)."""
    return re.sub(re.escape(begin) + ".*?" + re.escape(end), lambda _: block, text, flags=re.S)


def write_usb(block: str, summary: str) -> None:
    readme = README.read_text()
    if SUMMARY_BEGIN not in readme:
        raise SystemExit(f"{README} has no {SUMMARY_BEGIN} ... {SUMMARY_END} block")
    README.write_text(replace_block(readme, SUMMARY_BEGIN, SUMMARY_END, summary))
    path = PERFORMANCE_DOC
    text = path.read_text()
    if USB_BEGIN in text:
        text = replace_block(text, USB_BEGIN, USB_END, block)
    else:
        text = text.rstrip("\n") + "\n\n## Per USB adapter\n\n" + block + "\n"
    path.write_text(text)


def measure_failsafe() -> dict:
    """tools/bench_failsafe.py's figures (a served bench in real time: seconds per far end)."""
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "bench_failsafe.py"), "--json"],
                       capture_output=True, text=True, cwd=ROOT)
    if r.returncode:
        raise RuntimeError(f"bench_failsafe.py failed:\n{r.stderr[-3000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def render_failsafe(figures: dict, date: str) -> str:
    """The failsafe's table: host death to shaft at rest, per far end, armed and disarmed."""
    sys.path.insert(0, str(ROOT / "tools"))
    from bench_failsafe import describe
    ref = figures["reference_stop_s"]

    def fig(v: float | None) -> str:
        return "never" if v is None else f"{v * 1e3:.1f} ms"

    lines = [
        FAILSAFE_BEGIN,
        f"Measured {date} by `{COMMAND}` (or `--only-failsafe`; the figures are "
        "`python3 tools/bench_failsafe.py`'s), on the simulator's clock: a served bench "
        "(`lm629 sim serve`'s code) with two chips, a client process that started both in "
        "velocity mode (2 counts/sample) and was killed with SIGKILL. From the client's last "
        "frame (the trip report: the bridge's time of the trip minus the silence it saw) to "
        "the last moment either shaft moved. The failsafe is 0.5 s, abrupt stop; the same "
        f"abrupt stop sent by a live host comes to rest {ref * 1e3:.1f} ms after it. With "
        "`failsafe=0` (the bridge disarmed, as a host without the failsafe leaves it) the "
        "shafts still turn 2 s later: never.",
        "",
        "| far end | host death to shaft at rest | `failsafe=0` |",
        "|---|---|---|",
    ]
    for fe, f in figures["far_ends"].items():
        lines.append(f"| {describe(fe)} | {fig(f['armed'])} | {fig(f['disarmed'])} |")
    lines.append(FAILSAFE_END)
    return "\n".join(lines)


def write_failsafe(block: str) -> None:
    path = PERFORMANCE_DOC
    text = path.read_text()
    if FAILSAFE_BEGIN in text:
        text = replace_block(text, FAILSAFE_BEGIN, FAILSAFE_END, block)
    else:
        text = text.rstrip("\n") + "\n\n## Link failsafe\n\n" + block + "\n"
    path.write_text(text)


def probe_after() -> dict:
    """The figures only measured now: the other transports, the variants of waiting."""
    import lm629_host
    import lm629_host.chip.waiting as lm
    from lm629_host.sim.bridge import BridgeEmulator, EmuPipe
    from lm629_host.transports.simemu import EmuLinkTransport
    from lm629_host.bridge.protocol import HelloInfo
    from lm629_host.sim.build import build_model

    out: dict = {}
    # waiting: as on a wall clock (one exchange per 250 ms), and an old bridge (host polls)
    saved = lm.WAIT_STATUS_MAX_MS
    lm.WAIT_STATUS_MAX_MS = lm.WAIT_STATUS_WALL_CHUNK_MS
    try:
        out["wait_emu_wall"] = _link_wait("sim+emu://?baud=115200")
        out["wait_avr_wall"] = _link_wait("sim+avr://?baud=115200")
    finally:
        lm.WAIT_STATUS_MAX_MS = saved
    model = build_model("sim://")
    emu = BridgeEmulator(model, info=HelloInfo(capabilities=0x07))  # no WAIT_STATUS
    t = EmuLinkTransport(emu, model, EmuPipe(emu, baud=115200), "sim+emu://", baud=115200)
    out["wait_emu_old_bridge"] = _link_wait("", transport=t)
    out["wait_ftdi"] = _link_wait("sim+ftdi://")  # no far-side wait: the host polls
    # the FT232H waiting on the busy bit in the adapter: no "before"
    out["ftdi_busy_pin"] = _timed_commands(FTDI_BUSY_PIN)

    # exchanges per typed command: bridge round trips (sim+emu://), FT232H USB transfer pairs
    for url in ("sim+emu://", "sim+ftdi://", FTDI_BUSY_PIN):
        chip = _chip(url)
        trips = {}
        for name, fn in (("rdrp", chip.read_real_position),
                         ("ltrj_stt", lambda: chip.load_trajectory(
                             acceleration=100, velocity=65536, position=500, start=True)),
                         ("reset", chip.reset)):
            chip.load_trajectory(stop="off", start=True)
            r0 = chip.transport.stats.round_trips
            fn()
            trips[name] = chip.transport.stats.round_trips - r0
        out["trips " + url] = trips

    # the chip model alone (tools/bench_model.py's measure), bring-up end to end
    sys.path.insert(0, str(ROOT / "tools"))
    import bench_model
    from lm629_host.bench.bringup import run_bringup

    out["model_move_x"] = _median3(lambda: bench_model.measure("move", "auto", 10.0, 0.1)[0])

    def bringup() -> float:
        c = lm629_host.open("sim://")
        w0 = time.perf_counter()
        run_bringup(c)
        return time.perf_counter() - w0

    out["bringup_s"] = _median3(bringup)
    return out


# ------------------------------------------------------------------ builds
def _timed_run(cmd: list[str], cwd: Path) -> tuple[float, float]:
    """Wall seconds and peak resident MB of ``cmd`` (GNU time), or raises."""
    r = subprocess.run(["/usr/bin/time", "-f", "%e %M", *cmd], cwd=cwd, capture_output=True,
                       text=True)
    if r.returncode:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{r.stderr[-1500:]}")
    wall, kb = r.stderr.strip().splitlines()[-1].split()
    return float(wall), int(kb) / 1024


def compile_link_c(fw: Path) -> dict:
    """One compile of link.c with the host's gcc and with avr-gcc (the Makefile's flags)."""
    with tempfile.TemporaryDirectory() as tmp:
        host = _timed_run(["cc", "-O2", "-g", "-std=c99", "-Wall", "-Wextra", "-I.", "-c",
                           "link.c", "-o", f"{tmp}/link.o"], fw)
        avr = _timed_run(["avr-gcc", "-mmcu=atmega328p", "-DF_CPU=16000000UL", "-Os",
                          "-std=gnu99", "-c", "link.c", "-o", f"{tmp}/link_avr.o"], fw)
    return {"host": host, "avr": avr}


def whole_build() -> tuple[float, float]:
    """``make -B firmware harness`` on a copy of firmware_bridge/ (both images, the harness)."""
    with tempfile.TemporaryDirectory() as tmp:
        dst = Path(tmp) / "firmware_bridge"
        shutil.copytree(ROOT / "firmware_bridge", dst, ignore=shutil.ignore_patterns("build"))
        return _timed_run(["make", "-s", "-B", "firmware", "harness"], dst)


def fresh_clone_tests(ref: str) -> tuple[float, float, str]:
    """A fresh clone of ``ref``: venv, ``pip install -e '.[test]'``, then the test run timed
    (wall, peak MB of pytest and what it builds, its summary line)."""
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp) / "clone"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(d)], check=True)
        subprocess.run(["git", "-C", str(d), "checkout", "-q", ref], check=True)
        subprocess.run([sys.executable, "-m", "venv", ".venv"], cwd=d, check=True)
        py = str(d / ".venv" / "bin" / "python3")
        subprocess.run([py, "-m", "pip", "install", "-q", "-e", ".[test]"], cwd=d,
                       check=True, capture_output=True)
        r = subprocess.run(["/usr/bin/time", "-f", "%e %M", py, "-m", "pytest", "-q",
                            "-p", "no:cacheprovider"], cwd=d, capture_output=True, text=True)
        wall, kb = r.stderr.strip().splitlines()[-1].split()
        summary = r.stdout.strip().splitlines()[-1] if r.stdout.strip() else "?"
        return float(wall), int(kb) / 1024, summary


def probe_idle() -> dict:
    """Per far end: how far ``clock.sleep(10.0)`` moves the chip's clock (simulated s, exact),
    and how many times real time an idle simulated minute runs (``clock.sleep(60.0)``, wall
    clock: the failsafe armed, fed all the while)."""
    import lm629_host

    out = {}
    for url in IDLE_URLS:
        chip = lm629_host.open(url)
        model = getattr(chip.transport, "model")  # noqa: B009 - a simulator's, not typed on Transport
        t0 = model.now()
        chip.clock.sleep(10.0)
        slept = model.now() - t0
        w = time.perf_counter()
        chip.clock.sleep(60.0)
        out[url] = {"sleep10": slept, "speed": 60.0 / (time.perf_counter() - w)}
        chip.close()
    return out


def render_idle(before: list[dict], after: list[dict], date: str, baseline: str) -> str:
    """The idle table: medians of the runs, before and after."""
    lines = [
        f"Measured {date} by `{COMMAND}` (or `--only-idle`): `chip.clock.sleep(10.0)` on the "
        "simulated far ends with the failsafe armed (0.5 s), on the chip's clock (exact), and "
        "an idle simulated minute (`clock.sleep(60.0)`) in times real time (wall clock, "
        f"median of 3 in turn with the baseline {baseline}, on a shared 2-core machine).",
        "",
        "| far end | `sleep(10.0)` before | after | idle minute before | after |",
        "|---|---|---|---|---|"]
    for url in IDLE_URLS:
        b = [r[url] for r in before]
        a = [r[url] for r in after]
        lines.append(
            f"| `{url}` | {statistics.median(x['sleep10'] for x in b):.4f} s "
            f"| {statistics.median(x['sleep10'] for x in a):.4f} s "
            f"| {statistics.median(x['speed'] for x in b):.0f}x "
            f"| {statistics.median(x['speed'] for x in a):.0f}x |")
    return "\n".join(lines)


def write_idle(block: str) -> None:
    text = PERFORMANCE_DOC.read_text()
    if IDLE_BEGIN in text:
        text = replace_block(text, IDLE_BEGIN, IDLE_END, block)
    else:
        text = (text.rstrip("\n") + "\n\n## Idle simulated time\n\n"
                + f"{IDLE_BEGIN}\n{block}\n{IDLE_END}\n")
    PERFORMANCE_DOC.write_text(text)


def measure_idle(baseline: str) -> str:
    date = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    with tempfile.TemporaryDirectory() as tmp:
        old = Path(tmp)
        unpack(baseline, old)
        shutil.copytree(ROOT / "firmware_bridge" / "build", old / "firmware_bridge" / "build",
                        dirs_exist_ok=True)
        before, after = [], []
        for _ in range(3):  # in turn, so that both see the same load
            before.append(run_probe("idle", old))
            after.append(run_probe("idle", ROOT))
    return render_idle(before, after, date, baseline)


# ------------------------------------------------------------------ the baseline tree
def unpack(ref: str, dest: Path) -> None:
    """The baseline commit's sources into ``dest``, with its C sample loop built in place."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref], capture_output=True,
                             check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    subprocess.run([sys.executable, "setup.py", "-q", "build_ext", "--inplace"], cwd=dest,
                   capture_output=True, check=True)


def run_probe(name: str, path: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(path))
    r = subprocess.run([sys.executable, str(Path(__file__)), "--probe", name], env=env,
                       capture_output=True, text=True, cwd=path)
    if r.returncode:
        raise RuntimeError(f"probe {name} on {path} failed:\n{r.stderr[-3000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


# ------------------------------------------------------------------ other benchmarks run clean
OTHERS = [
    ["bench_core.py", "--n", "200"],
    ["bench_model.py", "--seconds", "1"],
    ["bench_link.py", "--n", "20"],
    ["bench_bridge.py", "--n", "10"],
    ["bench_ftdi.py", "--repeat", "5"],
    ["bench_cli.py", "--repeats", "1"],
    ["bench_predict.py", "--motors", "default"],
    ["fault_soak.py", "--runs", "1", "--n", "200"],
]


def run_others() -> tuple[list[str], dict[str, str]]:
    """Run each; the failures, and the last line each printed."""
    bad, last = [], {}
    for args in OTHERS:
        r = subprocess.run([sys.executable, str(ROOT / "tools" / args[0]), *args[1:]],
                           capture_output=True, text=True, cwd=ROOT)
        if r.returncode:
            bad.append(f"{' '.join(args)}: exit {r.returncode}: {r.stderr.strip()[-300:]}")
        lines = r.stdout.strip().splitlines()
        last[args[0]] = lines[-1] if lines else ""
    return bad, last


def firmware_size() -> str:
    r = subprocess.run(["make", "-s", "-C", str(ROOT / "firmware_bridge"), "size"],
                       capture_output=True, text=True)
    m = re.search(r"flash (\d+) of (\d+) bytes.*RAM (\d+) of (\d+)", r.stdout)
    return f"flash {m[1]} of {m[2]} bytes, static RAM {m[3]} of {m[4]}" if m else "?"


# ------------------------------------------------------------------ the table
def rows(before: dict, after: dict, extra: dict, builds: dict) -> list[tuple[str, str, str, str]]:
    """(figure, before, after, target) for the README."""
    def x(a: float, b: float) -> str:
        return f"{a / b:.1f}x better"

    bc, ac = builds["before_link"], builds["after_link"]
    r = [
        ("one compile of `firmware_bridge/link.c`, host gcc: wall, peak memory",
         f"{bc['host'][0]:.1f} s, {bc['host'][1]:.0f} MB", f"{ac['host'][0]:.2f} s, "
         f"{ac['host'][1]:.0f} MB", "<= 1 s, <= 200 MB"),
        ("one compile of `link.c`, avr-gcc", f"{bc['avr'][0]:.1f} s, {bc['avr'][1]:.0f} MB",
         f"{ac['avr'][0]:.2f} s, {ac['avr'][1]:.0f} MB", "<= 1 s, <= 200 MB"),
        ("whole firmware build (`make -B firmware harness`: two images + simavr harness)", "-",
         f"{builds['whole'][0]:.1f} s, {builds['whole'][1]:.0f} MB", ""),
        ("`wait_for` on a 21.7 s move, `sim://`, x real time", f"{before['wait_x']:.0f}x",
         f"{after['wait_x']:.0f}x ({after['wait_x'] / before['wait_x']:.0f}x faster)",
         ">= 2000x"),
        ("`sim://` host cost, `read_real_position()` (RDRP)", f"{before['rdrp_us']:.1f} us",
         f"{after['rdrp_us']:.1f} us ({x(before['rdrp_us'], after['rdrp_us'])})", ">= 2x better"),
        ("`sim://` host cost, LTRJ (6 words) + STT", f"{before['ltrj_stt_us']:.1f} us",
         f"{after['ltrj_stt_us']:.1f} us ({x(before['ltrj_stt_us'], after['ltrj_stt_us'])})",
         ">= 2x better"),
        ("`sim://` per RDRP / per LTRJ+STT: bus cycles, busy polls, simulated us (must not change)",
         _counts(before), _counts(after), "identical"),
        ("`sim://` host cost in Python bytecode instructions, RDRP / LTRJ(6)+STT (exact)",
         _bytecodes_cell(before), _bytecodes_cell(after, before), ""),
        ("link bytes/s during a 10 s wait, `sim+emu://` 115200 baud",
         f"{before['wait_emu']['bps']:.0f} B/s ({before['wait_emu']['round_trips']} round trips)",
         f"{after['wait_emu']['bps']:.1f} B/s ({after['wait_emu']['round_trips']} round trip, "
         f"WAIT_STATUS on the bridge); on a wall clock (a 250 ms exchange, so that Ctrl-C stays "
         f"prompt) {extra['wait_emu_wall']['bps']:.0f} B/s, the compiled firmware (`sim+avr://`) "
         f"{extra['wait_avr_wall']['bps']:.0f} B/s; a bridge without WAIT_STATUS (host polls "
         f"at the wait's rate) {extra['wait_emu_old_bridge']['bps']:.0f} B/s "
         f"({extra['wait_emu_old_bridge']['round_trips']} reads); FT232H (`sim+ftdi://`, host "
         f"polls) {extra['wait_ftdi']['bps']:.0f} B/s over USB "
         f"({extra['wait_ftdi']['round_trips']} reads)", ""),
        ("`sim://?record=1`, memory after 100k commands (SBPA + 2 words)",
         f"{before['record_mb']:.1f} MB (unbounded)", f"{after['record_mb']:.1f} MB "
         "(a window of 10,000: `record_window=`)", "bounded"),
    ]
    tb, ta = builds["transports_before"], builds["transports_after"]
    for url, name, target in (
            ("sim+avr://?baud=115200", "`sim+avr://` 115200 baud", ""),
            ("sim+avr://?baud=1000000", "`sim+avr://` 1,000,000 baud", "RDRP <= 300 us"),
            ("sim+ftdi://", "`sim+ftdi://` (emulated FT232H)",
             "<= 1.3x / 1.5x of 253 / 478 us (329 / 717)")):
        b, a = tb[url], ta[url]
        ratio = ""
        if url == "sim+ftdi://":
            ratio = (f" ({a['rdrp'] / FTDI_LIMIT_US['rdrp']:.2f}x / "
                     f"{a['ltrj_stt'] / FTDI_LIMIT_US['ltrj_stt']:.2f}x of the limits)")
        first = f"; RDRP whose program is new to the bridge {a['first']:.0f} us" \
            if url.startswith("sim+avr") else ""
        r.append((f"{name}: RDRP / LTRJ(6)+STT, simulated (bytes of one RDRP round trip)",
                  f"{b['rdrp']:.0f} us / {b['ltrj_stt']:.0f} us ({b['bytes']} B)",
                  f"{a['rdrp']:.0f} us / {a['ltrj_stt']:.0f} us ({a['bytes']} B){ratio}{first}",
                  target))
    fb = extra["ftdi_busy_pin"]
    r.append((f"`{FTDI_BUSY_PIN}` (D0 wired to GPIOL1, the adapter waits on busy): RDRP / "
              "LTRJ(6)+STT, simulated (bytes of one RDRP round trip)", "-",
              f"{fb['rdrp']:.0f} us / {fb['ltrj_stt']:.0f} us ({fb['bytes']} B) "
              f"({fb['rdrp'] / FTDI_LIMIT_US['rdrp']:.2f}x / "
              f"{fb['ltrj_stt'] / FTDI_LIMIT_US['ltrj_stt']:.2f}x of the limits)",
              "LTRJ(6)+STT <= 1.5x of 478 us (717)"))
    if "fresh" in builds:
        (bw, bm, bs), (aw, am, as_) = builds["fresh"]
        r.append((f"test run of a fresh clone (`pytest -q` after `pip install -e '.[test]'`, "
                  f"firmware builds included; measured {builds['fresh_date']} with "
                  "`--fresh-clone`)", f"{bw:.0f} s, {bm:.0f} MB ({bs})",
                  f"{aw:.0f} s, {am:.0f} MB ({as_})", "faster"))
    te, tf = extra["trips sim+emu://"], extra["trips sim+ftdi://"]
    tw = extra["trips " + FTDI_BUSY_PIN]
    r += [
        ("exchanges per typed command, RDRP / LTRJ(6)+STT / `reset()`: serial bridge round "
         "trips; FT232H USB write+read pairs", "-",
         f"bridge {te['rdrp']} / {te['ltrj_stt']} / {te['reset']}; FT232H {tf['rdrp']} / "
         f"{tf['ltrj_stt']} / {tf['reset']}; FT232H with `busy_pin=gpiol1` {tw['rdrp']} / "
         f"{tw['ltrj_stt']} / {tw['reset']}", ""),
        ("bridge firmware size", "-", builds["size"], ""),
        ("exactly-once over a lossy link (`tools/fault_soak.py --runs 1 --n 200`, 0.2 % byte "
         "faults)", "-", builds["soak"].replace("total: ", "").replace("|", "/"), ""),
        ("chip model alone, 10 s move with the PID active, x real time", "-",
         f"{extra['model_move_x']:.0f}x", ""),
        ("`lm629 bringup` sequence on `sim://`, wall", "-", f"{extra['bringup_s']:.2f} s", ""),
    ]
    return r


def _counts(d: dict) -> str:
    a, b = d["rdrp_counts"], d["ltrj_stt_counts"]
    return (f"{a['bus_cycles']:.0f}, {a['busy_polls']:.0f}, {a['sim_us']:.2f} / "
            f"{b['bus_cycles']:.0f}, {b['busy_polls']:.0f}, {b['sim_us']:.2f}")


def render(table: list[tuple[str, str, str, str]], date: str, ref: str, bad: list[str],
           link_ref: str = LINK_BASELINE) -> str:
    lines = [
        BEGIN,
        f"Measured {date} by `{COMMAND}` (this table is its output: run it again to refresh);",
        f"\"before\" is commit {ref} measured in the same run ({link_ref} for the `sim+avr://` and",
        "`sim+ftdi://` rows). Wall-clock figures are medians of 3 on a shared 2-core machine",
        "(+/- 30 %); simulated figures are exact.",
        "",
        "| figure | before | after | target |",
        "|---|---|---|---|",
    ]
    lines += [f"| {a} | {b} | {c} | {d} |" for a, b, c, d in table]
    if not any(a.startswith("test run of a fresh clone") for a, *_ in table):
        kept = previous_fresh_row()
        if kept:
            lines.append(kept)
    lines.append("")
    lines.append("Every benchmark in `tools/` ran clean in the same run." if not bad else
                 "Benchmarks that failed: " + "; ".join(bad))
    lines.append(END)
    return "\n".join(lines)


#: where the table lives (the README links to it)
PERFORMANCE_DOC = ROOT / "docs" / "performance.md"


def previous_fresh_row() -> str | None:
    """The fresh-clone row of the README's table, kept when this run does not remeasure it
    (it takes minutes: ``--fresh-clone``); it carries its own date."""
    m = re.search(r"^\| test run of a fresh clone .*$", PERFORMANCE_DOC.read_text(),
                  flags=re.M)
    return m[0] if m else None


def write_readme(block: str) -> None:
    path = PERFORMANCE_DOC
    text = path.read_text()
    if BEGIN in text:
        text = replace_block(text, BEGIN, END, block)
    else:
        head, sep, rest = text.partition("## Performance\n")
        if not sep:
            raise SystemExit(f"{PERFORMANCE_DOC} has no '## Performance' section")
        nxt = re.search(r"^## ", rest, flags=re.M)
        tail = rest[nxt.start():] if nxt else ""
        text = f"{head}{sep}\n{block}\n\n{tail}"
    path.write_text(text)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--write-readme", action="store_true")
    ap.add_argument("--baseline", default=BASELINE)
    ap.add_argument("--link-baseline", default=LINK_BASELINE,
                    help="'before' of the sim+avr:// and sim+ftdi:// rows (default %(default)s)")
    ap.add_argument("--fresh-clone", action="store_true",
                    help="also time the test run of a fresh clone, before and after (minutes)")
    ap.add_argument("--only-usb", action="store_true",
                    help="only the per-adapter table (docs/usb.md's links; about a minute)")
    ap.add_argument("--only-failsafe", action="store_true",
                    help="only the failsafe's table (a served bench in real time; ~15 s)")
    ap.add_argument("--only-idle", action="store_true",
                    help="only the idle simulated time (sim+avr://, sim+emu://; ~1 minute)")
    ap.add_argument("--idle-baseline", default=IDLE_BASELINE,
                    help="'before' of the idle rows (default %(default)s)")
    ap.add_argument("--probe", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.probe:
        print(json.dumps({"core": probe_core, "cost": probe_cost, "after": probe_after,
                          "transports": probe_transports, "usb": probe_usb,
                          "idle": probe_idle}[args.probe]()))
        return 0
    if args.only_idle:
        block = measure_idle(args.idle_baseline)
        print(block)
        if args.write_readme:
            write_idle(block)
        return 0

    date = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    print("the link failsafe ...", file=sys.stderr)
    failsafe_block = render_failsafe(measure_failsafe(), date)
    print(failsafe_block)
    if args.write_readme:
        write_failsafe(failsafe_block)
    if args.only_failsafe:
        return 0
    print("per USB adapter ...", file=sys.stderr)
    usb = run_probe("usb", ROOT)
    usb_block, summary = render_usb(usb, date), render_usb_summary(usb)
    print(usb_block)
    print(summary)
    if args.write_readme:
        write_usb(usb_block, summary)
    if args.only_usb:
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        old = Path(tmp)
        print(f"unpacking the baseline {args.baseline} ...", file=sys.stderr)
        unpack(args.baseline, old)
        print("compiling link.c, before and after ...", file=sys.stderr)
        builds = {"before_link": compile_link_c(old / "firmware_bridge"),
                  "after_link": compile_link_c(ROOT / "firmware_bridge"),
                  "whole": whole_build()}
        print("probes, before and after ...", file=sys.stderr)
        before = run_probe("core", old)
        after = run_probe("core", ROOT)
        with tempfile.TemporaryDirectory() as tmp2:
            link_old = Path(tmp2)
            print(f"unpacking the link baseline {args.link_baseline} ...", file=sys.stderr)
            unpack(args.link_baseline, link_old)
            builds["transports_before"] = run_probe("transports", link_old)
        builds["transports_after"] = run_probe("transports", ROOT)
        runs: dict[str, list[dict]] = {"before": [], "after": []}
        for _ in range(3):  # in turn, so that both see the same load
            runs["before"].append(run_probe("cost", old))
            runs["after"].append(run_probe("cost", ROOT))
    for d, key in ((before, "before"), (after, "after")):
        for name in runs[key][0]:
            d[name] = statistics.median(r[name] for r in runs[key])
    extra = run_probe("after", ROOT)
    if args.fresh_clone:
        print("fresh clones: pip install and the test run, before and after ...",
              file=sys.stderr)
        builds["fresh"] = (fresh_clone_tests(args.baseline), fresh_clone_tests("HEAD"))
        builds["fresh_date"] = date[:10]
    print("the other benchmarks ...", file=sys.stderr)
    bad, last = run_others()
    builds["size"] = firmware_size()
    builds["soak"] = last.get("fault_soak.py", "?")
    block = render(rows(before, after, extra, builds), date, args.baseline, bad,
                   args.link_baseline)
    print(block)
    if args.write_readme:
        write_readme(block)
        print(f"{PERFORMANCE_DOC}: table written", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
