"""The selftest's script, check by check (docs/selftest.md's table): the digital core in
lockstep (:func:`check_core`), the faults read from it (positions that are not the model's, the
other chip, HI), the clock, busy times, the chip selects, and with ``motion`` the encoder and
the index; and the index probe that tells a shaft resting on the index (:func:`index_at_rest`).

Why a module of its own: these say what is measured and what each finding means; how the
two sides are kept in step is :mod:`.lockstep`'s, what becomes of the findings
:mod:`.report`'s.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence

from lm629_host.bus.opcodes import (
    BUSY_BIT,
    BUSY_WORST_CASE_S,
    COMMANDS,
    FIXED_ONE,
    SAMPLE_CLOCKS,
    Cmd,
    Status,
    TrajectoryFlags,
)
from lm629_host.chip.lm629 import LM629
from lm629_host.chip.safety import emergency_stop, stop_on_error
from lm629_host.chip.supervise import search_index
from lm629_host.errors import AxisError, LM629Error, WaitTimeout
from lm629_host.bench.selftest.lockstep import SLOW, Lockstep, words_of
from lm629_host.bench.selftest.report import Fault, Measurement

#: the clock run: long enough that a 6 MHz chip (25 % off 8 MHz) is unmistakable and a host
#: paused for part of it moves the median of the slopes by nothing
CLOCK_RUN_S = 0.5


CLOCK_ROWS = 50


#: the commands whose busy time after the command byte is measured (none of them acts: the
#: probe repeats each, and an action repeated within 10 ms is a fault of its own)
BUSY_COMMANDS = (Cmd.RDSIGS, Cmd.RDDP, Cmd.MSKI, Cmd.RSTI, Cmd.LPEI, Cmd.LTRJ)


#: the breakpoint of the velocity run, counts: reached after 8 x 16 samples
BREAKPOINT_AT = 8


#: a position-mode move with a long cruise at SLOW: the reads in its middle are in the cruise
CRUISE_TO = 40


#: the samples a SIP is given, motor off, to latch an index under the shaft
INDEX_PROBE_SAMPLES = 3


#: the name of the index probe's measurement (shown, never judged: where a shaft rests is
#: the bench's business)
INDEX_AT_REST = "index: under the shaft at rest"


def latch_wait_us(clock_hz: float) -> int:
    """The wait after SIP by which an index under a shaft at rest has surely latched:
    :data:`INDEX_PROBE_SAMPLES` samples at ``clock_hz`` (a chip clocked up to 3 times slower
    than that still runs a whole sample in it)."""
    return math.ceil(INDEX_PROBE_SAMPLES * SAMPLE_CLOCKS / clock_hz * 1e6)


def index_at_rest(chip: LM629) -> bool:
    """True when the shaft rests on the encoder's index: after a reset (motor off) a SIP
    latches the index within :data:`INDEX_PROBE_SAMPLES` samples with nothing turning.  The
    model's index is half a turn from its shaft (model choice 20), so a bench parked on its
    index would read INDEX_PULSE after SIP and DFH where the model does not: the model is
    built with its index under its shaft instead."""
    chip.reset()
    chip.run(chip.program().command(Cmd.SIP))
    chip.clock.sleep(INDEX_PROBE_SAMPLES * SAMPLE_CLOCKS / chip.clock_hz)
    return bool(chip.read_status() & Status.INDEX_PULSE)


def check_core(ls: Lockstep) -> Fault | None:
    """The digital core, motor off (filter gains 0: the trajectory runs, nothing drives).
    Returns the fault that stopped it early (positions that are not the model's after a
    reset: no timed read could be matched), else None."""
    for side in ls.sides():
        side.reset()
    ls.out.append(Measurement("core", "reset: status", "/RST (or RESET); MSKI; RSTI",
                              None if ls.chip is None else int(ls.chip.read_status()),
                              int(ls.model.read_status()), unit="hex"))
    every = [("r", c) for c in (Cmd.RDSIGS, Cmd.RDDP, Cmd.RDRP, Cmd.RDDV, Cmd.RDRV, Cmd.RDSUM,
                                Cmd.RDIP)]
    ls.step("after reset", [("s",), *every])
    fault = positions_fault(ls)
    if fault is not None:
        return fault
    ls.step("masks", [("w", Cmd.MSKI, int(Status.BREAKPOINT)), ("w", Cmd.LPEI, 0x7FFF),
                      ("w", Cmd.SBPA, 0, BREAKPOINT_AT), ("w", Cmd.RSTI, 0), ("s",),
                      ("r", Cmd.RDSIGS)])
    # UDF acts at the next sample, which sets signals bit 13 for that one sample: read once
    # two samples have surely passed, never right after (on a bench a sample may pass
    # within the program, on the model it does not)
    ls.step("filter 0", [("p", lambda c: c.filter_program(kp=0, ki=0, kd=0, il=0)),
                         ("w", Cmd.UDF), ("s",)])
    ls.pause(0.002)
    ls.step("filter updated", [("s",), ("r", Cmd.RDSIGS)])
    # velocity mode at 1/16 count a sample: the breakpoint interrupt, HI, RDDP over time
    ls.step("velocity start", [("p", lambda c: c.trajectory_program(
        acceleration=SLOW, velocity=SLOW, velocity_mode=True)), ("w", Cmd.STT), ("s",),
        ("r", Cmd.RDSIGS)])
    ls.started()
    reads = [("s",), ("r", Cmd.RDSIGS), ("r", Cmd.RDDV), ("r", Cmd.RDRP)]
    if ls.chip is not None:
        ls.chip.clock.sleep(0.004)
    ls.timed("velocity before the breakpoint", reads, per_sample=1 / 16, hi=True)
    if ls.chip is not None:
        ls.chip.clock.sleep((BREAKPOINT_AT + 3) * 16 * SAMPLE_CLOCKS / ls.model.clock_hz)
    ls.timed("velocity past the breakpoint", reads, per_sample=1 / 16, hi=True)
    ls.step("interrupt reset", [("w", Cmd.RSTI, 0), ("s",), ("r", Cmd.RDSIGS)])
    ls.pause(0.012)
    # the stop from 1/16 count a sample ends at the next sample: its status is read after
    ls.step("stop smooth", [("p", lambda c: c.trajectory_program(stop="smooth")),
                            ("w", Cmd.STT)])
    ls.pause(0.012)
    ls.step("stopped", [("s",), ("r", Cmd.RDSIGS), ("r", Cmd.RDDV)])
    # position mode: a cruise at 1/16 count a sample, read in its middle and at its end
    target = ls.model.read_desired_position() + CRUISE_TO
    ls.step("position start", [("w", Cmd.RSTI, 0), ("p", lambda c: c.trajectory_program(
        acceleration=SLOW // 4, velocity=SLOW, position=target)), ("w", Cmd.STT), ("s",)])
    ls.started()
    if ls.chip is not None:
        ls.chip.clock.sleep(CRUISE_TO / 2 * 16 * SAMPLE_CLOCKS / ls.model.clock_hz)
    ls.timed("position cruising", reads, per_sample=1 / 16)
    for side in ls.sides():
        side.wait_for(Status.TRAJECTORY_COMPLETE, timeout=2 * CRUISE_TO * 16 * SAMPLE_CLOCKS
                      / ls.model.clock_hz + 1.0, what="the position-mode move to complete")
    ls.step("position done", [("s",), ("r", Cmd.RDSIGS), ("r", Cmd.RDDP), ("r", Cmd.RDDV)])
    # SIP latches an index under a shaft at rest at the first sample after it; whether that
    # sample falls before a read right after SIP (or after DFH) depends on where in its
    # sample period the SIP landed, which nothing makes the same on the chip and the model
    # (a wait's end, a late host, a slow adapter): the reads wait until the latch is decided
    ls.step("index armed", [("w", Cmd.SIP), ("t", latch_wait_us(ls.model.clock_hz)), ("s",),
                            ("r", Cmd.RDSIGS), ("r", Cmd.RDIP)])
    ls.step("home", [("w", Cmd.DFH), ("s",), ("r", Cmd.RDDP), ("r", Cmd.RDRP)])
    ls.pause(0.012)
    ls.step("motor off", [("p", lambda c: c.trajectory_program(stop="off")), ("w", Cmd.STT),
                          ("s",), ("r", Cmd.RDSIGS)])
    # the one command an LM628 takes and an LM629 refuses (its command-error bit): sent on
    # either profile, motor off, so that an LM628 on an LM629 profile (or the other way
    # round) is named; PORT8 and an RSTI after it leave the chip as before
    ls.step("12-bit port", [("w", Cmd.RSTI, 0), ("w", Cmd.PORT12), ("s",), ("r", Cmd.RDSIGS)])
    ls.step("8-bit port", [("w", Cmd.PORT8), ("w", Cmd.RSTI, 0), ("s",), ("r", Cmd.RDSIGS)])
    return None


def positions_fault(ls: Lockstep) -> Fault | None:
    """The chip's positions after its reset where the model's are 0 (a chip reset by
    something else, a simulator's ``reset_position``): every timed read of the core is taken
    at the chip's desired position, which the model would have to be run to from 0 (hours of
    model time, or never): the core stops, saying so."""
    read = {m.name: m.measured for m in ls.out[-8:] if m.measured is not None}
    want = {m.name: m.expected for m in ls.out[-8:]}
    names = ("after reset: RDDP", "after reset: RDRP")
    if not all(n in read for n in names) or all(read[n] == want[n] for n in names):
        return None
    dp, rp = (read[n] for n in names)
    return Fault("positions", f"the chip's desired and real positions read {dp} and {rp} after "
                              f"its reset, where a reset leaves {want[names[0]]} and "
                              f"{want[names[1]]}: its positions are not the model's, so no "
                              "timed read can be matched (the core stopped there)",
                 "check that the reset reaches this chip (/RST, pin 27; or the RESET command "
                 "on a bridge without the line) and that nothing else drives it; a simulator's "
                 "reset_position= makes exactly this")


def variant_fault(ls: Lockstep) -> Fault | None:
    """An LM628 where the profile says LM629, or the other way round: PORT12's command-error
    bit (status bit 1) on the chip is not the model's."""
    m = next((m for m in ls.out if m.name == "12-bit port: status"), None)
    if m is None or m.measured is None or not (m.measured ^ m.expected) & Status.COMMAND_ERROR:
        return None
    profile = ls.model.variant.upper()
    chip = "LM628" if profile == "LM629" else "LM629"
    took = "took PORT12 (the 12-bit DAC port) without" if chip == "LM628" else \
        "refused PORT12 (the 12-bit DAC port) with"
    return Fault("chip", f"the chip {took} a command error: it is an {chip}, the profile says "
                         f"{profile}",
                 f"set the profile's chip to \"{chip.lower()}\" (or --chip {chip.lower()}) if "
                 f"that is the part on the board (an LM628 drives a DAC, an LM629 PWM)")


def hi_fault(ls: Lockstep) -> Fault | None:
    past = next((m for m in ls.out if m.name == "velocity past the breakpoint: HI pin"), None)
    before = next((m for m in ls.out if m.name == "velocity before the breakpoint: HI pin"), None)
    if past is None or before is None or past.measured is None:
        return None
    if past.expected and not past.measured:
        return Fault("HI", "HI (pin 17) stayed low while the chip raised its breakpoint "
                           "interrupt (signals bit 15 set): HI is not wired to the adapter",
                     "connect LM629 pin 17 (HI) to the adapter's HI input (the Uno's A5, the "
                     "FT232H's ADBUS5: `lm629 wiring` shows yours)")
    if before.measured and not before.expected:
        return Fault("HI", "HI (pin 17) read high with no interrupt pending: the line is stuck "
                           "high or wired to another signal",
                     "check the HI wire for a short to +5 V or a neighbouring pin")
    return None


def check_clock(ls: Lockstep, profile_hz: float) -> Fault | None:
    """The sample period against the transport's clock, from a velocity run at one count a
    sample (filter gains 0) recorded for :data:`CLOCK_RUN_S`."""
    chip = ls.chip
    expected = profile_hz / 1e6
    if chip is None:
        ls.out.append(Measurement("clock", "clock: measured", "velocity run, RDDP recorded",
                                  ls.replay["clock: measured"].measured
                                  if "clock: measured" in ls.replay else None, expected,
                                  unit="MHz"))
        return None
    chip.reset()
    chip.load_filter(kp=0, ki=0, kd=0, il=0)
    chip.update_filter()
    chip.load_trajectory(acceleration=FIXED_ONE, velocity=FIXED_ONE, velocity_mode=True,
                         start=True)
    try:
        trace = chip.record(CLOCK_RUN_S / CLOCK_ROWS, CLOCK_RUN_S)
    finally:
        chip.load_trajectory(stop="off", start=True)
    rows = list(trace)
    half = len(rows) // 2
    slopes = [(rows[i + half].desired - rows[i].desired) / (rows[i + half].t - rows[i].t)
              for i in range(len(rows) - half) if rows[i + half].t > rows[i].t]
    if not slopes:
        raise LM629Error("the clock run recorded too few rows to measure the sample period")
    mhz = statistics.median(slopes) * SAMPLE_CLOCKS / 1e6
    m = Measurement("clock", "clock: measured", f"velocity run at 1 count/sample, RDDP "
                    f"recorded {len(rows)} times over {CLOCK_RUN_S:g} s "
                    f"({chip.transport.record_note()})", round(mhz, 4), expected, unit="MHz")
    ls.out.append(m)
    if not m.differs:
        return None
    return Fault("clock", f"the chip's clock measures {mhz:.2f} MHz (sample period "
                          f"{SAMPLE_CLOCKS / mhz:.1f} us); the profile says {expected:g} MHz: "
                          f"every velocity and time is {abs(mhz / expected - 1) * 100:.0f} % off",
                 f"set the profile's clock to \"{mhz:.3g}MHz\" (or --clock {mhz:.3g}MHz) if "
                 "that is the crystal on the board; otherwise check the crystal and its "
                 "oscillator")


def _busy_after(chip: LM629, cmd: Cmd, wait_us: int) -> bool:
    """True when the chip reads busy ``wait_us`` after ``cmd``'s command byte (the command
    then completed normally, so nothing is left half done)."""
    p = chip.program().command(cmd)
    if wait_us:
        p.wait(wait_us)
    p.status()
    if COMMANDS[cmd].direction.value == "read":
        p.read(words_of(cmd))
    elif cmd is Cmd.LTRJ:
        p.write(int(TrajectoryFlags.VELOCITY_MODE | TrajectoryFlags.FORWARD))
    elif cmd is Cmd.MSKI:
        p.write(int(Status.BREAKPOINT))
    elif cmd is Cmd.LPEI:
        p.write(0x7FFF)
    else:
        p.write(0)
    return bool(chip.run(p).statuses[0] & BUSY_BIT)


def _busy_time(chip: LM629, cmd: Cmd) -> int | None:
    """The shortest far-side wait after which busy reads clear, us (None: never seen busy:
    the transport waits it out itself)."""
    if not _busy_after(chip, cmd, 0):
        return None
    lo, hi = 0, int(BUSY_WORST_CASE_S * 1e6) + 1  # busy at lo; at hi assumed clear
    if _busy_after(chip, cmd, hi):
        return hi
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if _busy_after(chip, cmd, mid):
            lo = mid
        else:
            hi = mid
    return hi


def check_busy(ls: Lockstep) -> None:
    for cmd in BUSY_COMMANDS:
        got = None if ls.chip is None else _busy_time(ls.chip, cmd)
        if ls.chip is None and f"busy: {cmd.name}" in ls.replay:
            got = ls.replay[f"busy: {cmd.name}"].measured
        ls.out.append(Measurement("busy", f"busy: {cmd.name}", f"{cmd.name}, wait, RDSTAT",
                                  got, _busy_time(ls.model, cmd), judged=False, unit="us"))


def check_selects(chip: LM629, selects: Sequence[int], out: list[Measurement]) -> list[Fault]:
    """Each chip select of the profile's axes answers with a status that is not FF (the
    undriven bus's pull-ups)."""
    faults = []
    for cs in selects:
        try:
            other = chip if cs == chip.chip_select else LM629(
                chip.transport, chip=chip.variant, axis=cs if cs else None)
            status = int(other.read_status())
        except AxisError as exc:
            out.append(Measurement("wiring", f"cs {cs}: answers", "RDSTAT", False, True))
            faults.append(Fault(f"cs {cs}", str(exc), "give the axis a chip select the adapter "
                                                       "has (`lm629 wiring` lists them)"))
            continue
        out.append(Measurement("wiring", f"cs {cs}: answers", "RDSTAT", status != 0xFF, True))
        if status == 0xFF:
            faults.append(Fault(f"cs {cs}", f"no chip answers on chip select {cs} (status "
                                            "reads FF: nothing drives the bus)",
                                f"check /CS {cs}'s wire to pin 12 of that chip, and the chip's "
                                "power and clock"))
    return faults


def check_motion(ls: Lockstep, lines: int, gains: dict[str, int]) -> list[Fault]:
    """The encoder counting and the index pulse: a slow velocity run (about a quarter turn a
    second) until the index is latched, with stop-on-error armed (an encoder that does not
    count makes the following error grow: the chip then turns the motor off itself)."""
    counts_per_rev = 4 * lines
    faults: list[Fault] = []
    counted: bool | None = None
    index: bool | None = None
    for side in ls.sides():
        period = SAMPLE_CLOCKS / side.clock_hz
        velocity = max(1, round(counts_per_rev / 4 * period * FIXED_ONE))
        side.reset()
        side.load_filter(**gains)
        side.update_filter()
        side.load_position_error(max(200, counts_per_rev // 8), stop=True)
        seen = True
        with stop_on_error(side):
            try:
                search_index(side, velocity, timeout=4 * 2.5 + 1.0)
            except WaitTimeout:
                seen = False
                emergency_stop(side)
        moved = abs(side.read_real_position())
        side.reset()
        if side is ls.model:
            ls.out.append(Measurement("wiring", "motion: encoder counts", "velocity run",
                                      counted, moved > 1))
            ls.out.append(Measurement("wiring", "motion: index seen", "SIP; velocity run",
                                      index, seen))
        else:
            counted, index = moved > 1, seen
            if not counted:
                faults.append(Fault("encoder", "the real position did not change while the "
                                               "chip drove the motor: the encoder does not count "
                                               "(or the shaft did not turn)",
                                    "check the encoder's A and B (pins 2, 3) and its supply; "
                                    "then the amplifier and the motor"))
            elif not seen:
                faults.append(Fault("index", "no index pulse in 2.5 revolutions while the "
                                             "encoder counted: the index is not wired",
                                    "connect the encoder's index channel to LM629 pin 1 (IN); "
                                    "an encoder without one cannot home on the index"))
    return faults


__all__ = ["BREAKPOINT_AT", "BUSY_COMMANDS", "CLOCK_ROWS", "CLOCK_RUN_S", "CRUISE_TO",
           "INDEX_AT_REST", "INDEX_PROBE_SAMPLES", "check_busy", "check_clock", "check_core",
           "check_motion", "check_selects", "hi_fault", "index_at_rest", "latch_wait_us",
           "positions_fault", "variant_fault"]
