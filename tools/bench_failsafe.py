#!/usr/bin/env python3
"""The link failsafe, measured: from a host's death to every shaft at rest, per far end.

    python3 tools/bench_failsafe.py [--far python,python+uno,firmware,firmware+uno]

A served bench (:class:`~lm629_host.sim.serve.SimServer`, the code behind ``lm629 sim
serve``, in this process so that :class:`RestWatch` can see the shafts on the simulator's
clock) with two chips; a client process opens ``serial://LINK``, starts both axes in
velocity mode (2 counts/sample) and is killed with SIGKILL.  The figure is the time from the
client's last frame (the trip report: the bridge's time of the trip minus the silence it
saw) to the last moment either shaft moved, in simulator seconds; with ``failsafe=0`` (the
bridge disarmed, as a host without the failsafe leaves it) the shafts are still turning
``NEVER_S`` later: "never".  The same abrupt stop sent by a live host is the reference
(:func:`reference_stop_s`): the figure is about failsafe (0.5 s) + that.  The served bench
runs in real time: about 2 s of wall time per far end.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from lm629_host.motion.board import Board
from lm629_host.sim.model import chips_of
from lm629_host.sim.serve import SimServer

#: the far ends measured ("+uno": behind an Arduino Uno R3's USB chip)
FAR_ENDS = ["python", "python+uno", "firmware", "firmware+uno"]
#: velocity mode at 2 counts/sample after a 0.01 counts/sample^2 ramp (51 ms)
SPEED, ACC = 131072, 655
#: how long a disarmed bridge is watched before its shafts count as turning for ever
NEVER_S = 2.0

CLIENT = textwrap.dedent(f"""\
    import os, sys, time
    from lm629_host.motion.board import open_board
    url, how = sys.argv[1], sys.argv[2]
    b = open_board(url, axes=2)
    b.reset()
    for ax in b.axes:
        ax.load_filter(kp=20, kd=100)
        ax.update_filter()
    def run():
        for ax in b.axes:
            ax.load_trajectory(acceleration={ACC}, velocity={SPEED}, velocity_mode=True,
                               start=True)
    if how == "raise":
        with b:
            run()
            print("moving", flush=True)
            b.clock.sleep(0.1)
            1 / 0
    run()
    print("moving", flush=True)
    if how == "unplug":  # the port goes away under a live process: no byte reaches the bridge
        os.close(b.transport.pipe.port.fd)
    time.sleep(60)
    """)


class RestWatch:
    """When each chip's shaft last moved, on the simulator's clock: the model runs in steps
    of 1 ms (8192 clocks at 8 MHz) while watching (:meth:`start`)."""

    STEP = 8192

    def __init__(self, model) -> None:
        self.chips = chips_of(model)
        self.pos = [c.motion.real_position for c in self.chips]
        self.moved = [0.0] * len(self.chips)
        self.watching = False
        for k, c in enumerate(self.chips):
            # the server's far end runs the model through advance_to: watched in 1 ms steps
            c.advance_to = self._stepper(k, c, c.advance_to)  # type: ignore[method-assign]  # a watch

    def _stepper(self, k, chip, advance):
        def advance_to(tick: int) -> None:
            if not self.watching:
                advance(tick)
                return
            while chip.tick < tick:
                advance(min(tick, chip.tick + self.STEP))
                if chip.motion.real_position != self.pos[k]:
                    self.pos[k], self.moved[k] = chip.motion.real_position, chip.now()
        return advance_to

    def start(self) -> None:
        """Watch from now: every shaft counts as moving now."""
        self.pos = [c.motion.real_position for c in self.chips]
        self.moved = [c.now() for c in self.chips]
        self.watching = True

    def at_rest_for(self, seconds: float) -> bool:
        now = self.chips[0].now()
        return all(now - m >= seconds for m in self.moved)

    def wait_rest(self, limit_s: float = 5.0) -> bool:
        """Wall time, as the served bench runs in real time: until every shaft rested 0.1 s
        (True), or ``limit_s`` (False)."""
        end = time.monotonic() + limit_s
        while not self.at_rest_for(0.1):
            if time.monotonic() >= end:
                return False
            time.sleep(0.02)
        return True


@contextmanager
def served(tmp: Path, far_end: str) -> Iterator[tuple[SimServer, RestWatch]]:
    """A two-chip bench served on ``tmp/bench`` (``firmware``: the compiled firmware in
    simavr; ``+uno``: behind the Uno's USB chip), with a :class:`RestWatch` on its chips."""
    kind, _, usb = far_end.partition("+")
    url = "sim://?axes=2" + (f"&usb={usb}" if usb else "")
    server = SimServer(tmp / "bench", url, firmware=kind == "firmware")
    watch = RestWatch(server.model)
    with server:
        server.start()
        yield server, watch


def lm629(link: Path, *args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).with_name("lm629")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "lm629_host"]
    return subprocess.run([*cmd, "--port", f"serial://{link}", *args], capture_output=True,
                          text=True, timeout=60, env=env)


def client(link: Path, how: str, query: str = "", env: dict[str, str] | None = None
           ) -> subprocess.Popen:
    """The client process, once both axes move (``how``: kill, unplug, raise)."""
    p = subprocess.Popen([sys.executable, "-c", CLIENT, f"serial://{link}{query}", how],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    assert p.stdout is not None and p.stderr is not None
    line = p.stdout.readline()
    if line.strip() != "moving":
        raise RuntimeError(f"the client did not start: {line}{p.stderr.read()}")
    return p


def status(link: Path, env: dict[str, str] | None = None) -> tuple[dict, str]:
    """``lm629 --axis 0,1 status --json`` (a new process: told of a trip) and its stderr."""
    p = lm629(link, "--axis", "0,1", "status", "--json", env=env)
    if p.returncode:
        raise RuntimeError(p.stderr)
    return json.loads(p.stdout), p.stderr


def death_to_rest(tmp: Path, far_end: str, query: str = "",
                  env: dict[str, str] | None = None) -> tuple[float | None, dict, str]:
    """SIGKILL a client mid velocity-mode move on a two-axis board; returns the time from its
    last frame to the last shaft at rest (simulator seconds; None: still turning NEVER_S after
    the kill), the next process's status and its stderr."""
    with served(tmp, far_end) as (server, watch):
        assert server.link is not None
        proc = client(server.link, "kill", query, env)
        watch.start()
        killed = watch.chips[0].now()
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        rested = watch.wait_rest(NEVER_S + 1.0)
        watch.watching = False
        st, err = status(server.link, env)
    trip = st["failsafe"]["trip"]
    if not rested or trip is None:
        assert max(watch.moved) - killed >= NEVER_S, (watch.moved, killed)
        return None, st, err
    return max(watch.moved) - (trip["at_s"] - trip["silent_s"]), st, err


def reference_stop_s(stop: str = "abrupt") -> float:
    """The same stop sent by a live host at the same speed (``sim+emu://``, two axes, the
    failsafe off): from the stop to the last shaft at rest, simulator seconds."""
    from lm629_host.transports.simemu import open_emulated
    t = open_emulated("sim+emu://?axes=2&failsafe=0")
    b = Board(t, axes=2)
    b.reset()
    for ax in b.axes:
        ax.load_filter(kp=20, kd=100)
        ax.update_filter()
        ax.load_trajectory(acceleration=ACC, velocity=SPEED, velocity_mode=True, start=True)
    b.clock.sleep(0.3)
    t0 = t.model.now()
    for ax in b.axes:
        ax.load_trajectory(stop=stop, start=True)
    pos = [c.motion.real_position for c in t.models]
    moved = [t0] * len(pos)
    while t.model.now() < t0 + 1.0:
        t.pipe.read(0.001)
        for k, c in enumerate(t.models):
            if c.motion.real_position != pos[k]:
                pos[k], moved[k] = c.motion.real_position, c.now()
    t.close()
    return max(moved) - t0


def measure(far_ends: list[str]) -> dict[str, dict[str, float | None]]:
    """{far end: {"armed": s, "disarmed": s or None}} (None: never at rest)."""
    import tempfile
    out: dict[str, dict[str, float | None]] = {}
    for fe in far_ends:
        with tempfile.TemporaryDirectory() as tmp:
            armed, _, _ = death_to_rest(Path(tmp), fe)
        with tempfile.TemporaryDirectory() as tmp:
            disarmed, _, _ = death_to_rest(Path(tmp), fe, "?failsafe=0")
        out[fe] = {"armed": armed, "disarmed": disarmed}
    return out


def describe(fe: str) -> str:
    kind, _, usb = fe.partition("+")
    name = "the Python far end" if kind == "python" else "the firmware (simavr)"
    return name + (f" behind `usb={usb}`" if usb else "")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--far", default=",".join(FAR_ENDS))
    ap.add_argument("--json", action="store_true", help="one JSON object on stdout")
    args = ap.parse_args()
    figures = measure(args.far.split(","))
    ref = reference_stop_s()
    if args.json:
        print(json.dumps({"reference_stop_s": ref, "far_ends": figures}))
        return 0
    print(f"the same abrupt stop sent by a live host: at rest {ref * 1e3:.1f} ms after it")
    for fe, f in figures.items():
        armed = "never" if f["armed"] is None else f"{f['armed'] * 1e3:.1f} ms"
        off = "never" if f["disarmed"] is None else f"{f['disarmed'] * 1e3:.1f} ms"
        print(f"{describe(fe)}: host death to shaft at rest {armed} (failsafe 0.5 s); "
              f"failsafe=0: {off}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
