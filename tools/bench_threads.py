"""What the transport lock costs, and what move_to puts on the link.

    python3 tools/bench_threads.py [--n 20000]

1. ``read_real_position()`` on ``sim://``, back to back, through ``Transport.execute`` (the
   lock, the chip-select check, the count, the observers) and straight through the transport's
   ``_execute``, in one process: the ratio is ``execute``'s share of a typed command.
2. The same reads from 4 threads sharing the chip (each bus program runs whole).
3. ``move_to`` + ``Move.wait`` on ``sim+emu://`` (the bridge's link protocol): round trips to
   start a move (the start snapshot, the flags, LTRJ and STT are one program) and for the
   whole move; a 10-call ``batch()``.
"""

from __future__ import annotations

import argparse
import threading
import time

import lm629_host


class _Unlocked(lm629_host.LM629):
    """An LM629 whose programs skip ``Transport.execute`` (this benchmark's reference only)."""

    def run(self, program):
        return self.transport._execute(program)


def _reads(chip, n: int) -> float:
    t0 = time.perf_counter()
    for _ in range(n):
        chip.read_real_position()
    return (time.perf_counter() - t0) / n


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=20000)
    n = ap.parse_args().n
    with lm629_host.open("sim://") as chip:
        chip.reset()
        t = chip.transport
        locked = min(_reads(chip, n) for _ in range(3))
        # the transport's own run of the program, without execute's lock, count and checks:
        # run() is LM629's one door to the bus, so an object of a subclass routes it there
        unlocked_chip = _Unlocked(t)
        unlocked = min(_reads(unlocked_chip, n) for _ in range(3))
        print(f"sim:// read_real_position: {locked * 1e6:.1f} us locked, {unlocked * 1e6:.1f} us "
              f"straight to _execute: x{locked / unlocked:.3f}")
        per = n // 4
        t0 = time.perf_counter()
        threads = [threading.Thread(target=_reads, args=(chip, per)) for _ in range(4)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        dt = (time.perf_counter() - t0) / (4 * per)
        print(f"4 threads sharing it: {dt * 1e6:.1f} us per call ({dt / locked:.2f} x one "
              "thread back to back)")
    with lm629_host.open("sim+emu://") as chip:
        chip.reset()
        chip.load_filter(kp=20)
        chip.update_filter()
        st = chip.transport.stats
        before = st.round_trips
        move = chip.move_to(1000, velocity=65536, acceleration=655)
        start = st.round_trips - before
        result = move.wait()
        print(f"sim+emu:// move_to(1000): {start} round trip(s) to start (one program: snapshot, "
              f"RSTI, LTRJ, STT), {st.round_trips - before} for the whole move; at rest "
              f"{result.error:+d} counts from the target after {result.duration:.3f} s simulated")
        before = st.round_trips
        with chip.batch() as b:
            for _ in range(5):
                b.read_real_position()
                b.read_desired_position()
        print(f"sim+emu:// batch() of 10 reads: {st.round_trips - before} round trip(s)")


if __name__ == "__main__":
    try:
        main()
    except BrokenPipeError:  # `| head`
        pass
