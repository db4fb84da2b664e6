"""The first hour with a new board, as one function: the bring-up of AN-706 2.12 and AN-868.

1. reset check (AN-706 4.4.1): status 00 at once, 84/C4 after 1.5 ms, 80/C0 after MSKI/RSTI;
2. loop phasing at kp = 1: a slow move; the shaft must follow the desired position.  With the
   motor leads (or the encoder channels) the wrong way round the loop is positive feedback and
   the shaft runs away the other way: "swap the motor leads";
3. kp = 20 hold: the shaft must come to rest inside the P-only dead band, 256 / kp counts
   (8-bit output: the drive is the top byte of kp x error, AN-706 5.2.4);
4. a small move (1000 counts by default);
5. its largest following error and its settle time into that dead band;
6. what to do next.

:func:`run_bringup` returns a :class:`BringupReport`; the CLI (``lm629 bringup``) only renders
it, so that the sequence is tested without click.  All waiting is on the chip's clock
(simulated time on ``sim://``).  Any exception while the motor may move stops it first
(:func:`lm629_host.safety.stop_on_error`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from .errors import ResetError
from .lm629 import LM629
from .opcodes import Status
from .program import Program, ProgramResult
from .safety import emergency_stop, stop_on_error
from .units import FIXED_ONE, Scale
from .wiring import wiring_suspects

#: exit codes of a bring-up (also documented by ``lm629 --help``)
EXIT_CHECK_FAILED = 1
EXIT_RESET_FAILED = 5


@dataclass(frozen=True)
class BringupOptions:
    """The numbers of the sequence (raw chip words and counts, AN-706 2.12 by default)."""

    phasing_kp: int = 1
    phasing_distance: int = 4000  #: counts; a slow move at kp = 1
    phasing_velocity: int = 2 * FIXED_ONE  #: 2 counts/sample: e = 256 (one output step) in ~130 samples
    phasing_acceleration: int = FIXED_ONE // 8
    phasing_time_s: float = 0.3
    #: the shaft moving this many counts against the desired direction is a runaway
    runaway_counts: int = 50
    hold_kp: int = 20
    hold_time_s: float = 0.5
    move_distance: int = 1000  #: counts
    move_velocity: int = FIXED_ONE // 2  #: 0.5 counts/sample
    move_acceleration: int = FIXED_ONE // 400  #: 200 samples of ramp
    settle_timeout_s: float = 2.0
    poll_s: float = 0.002

    @property
    def dead_band(self) -> int:
        """Counts of error a P-only loop at ``hold_kp`` leaves uncorrected (8-bit output),
        plus one for the encoder's quantisation."""
        return math.ceil(256 / self.hold_kp) + 1


@dataclass
class StepResult:
    """One step's verdict: ``ok`` True (pass), False (fail) or None (information, skipped)."""

    name: str
    ok: bool | None
    summary: str
    details: list[str] = field(default_factory=list)
    data: Mapping[str, object] = field(default_factory=dict)

    @property
    def verdict(self) -> str:
        return {True: "PASS", False: "FAIL", None: "----"}[self.ok]


@dataclass
class BringupReport:
    steps: list[StepResult] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return all(s.ok is not False for s in self.steps) and \
            any(s.name == "settle" and s.ok for s in self.steps)

    @property
    def exit_code(self) -> int:
        if self.steps and self.steps[0].name == "reset" and self.steps[0].ok is False:
            return EXIT_RESET_FAILED
        return 0 if self.passed else EXIT_CHECK_FAILED

    def step(self, name: str) -> StepResult | None:
        return next((s for s in self.steps if s.name == name), None)


def reset_with_statuses(chip: LM629) -> tuple[Status, list[int]]:
    """``chip.reset()``, also returning every status byte its programs read."""
    seen: list[int] = []
    run = chip.run

    def recording(program: Program) -> ProgramResult:
        result = run(program)
        seen.extend(result.statuses)
        return result

    chip.run = recording  # type: ignore[method-assign]  # this chip's programs only, for the report
    try:
        return chip.reset(), seen
    finally:
        del chip.run  # the instance attribute only: LM629.run again


def _hex(statuses: list[int] | tuple[int, ...]) -> str:
    return " ".join(f"{s:02X}" for s in statuses) or "nothing"


def run_bringup(chip: LM629, options: BringupOptions = BringupOptions(), *,
                confirm: Callable[[str], bool] = lambda question: True,
                announce: Callable[[str], None] = lambda text: None,
                report: Callable[[StepResult], None] = lambda step: None,
                clock_hz: float | None = None) -> BringupReport:
    """Run the sequence; stop at the first failed step.  ``confirm`` is asked before the motor
    first turns (False ends the sequence there); ``announce`` gets a line before each step,
    ``report`` each :class:`StepResult` as soon as it is known.  ``clock_hz`` (for the expected
    move time) defaults to the simulated chip's clock, else 8 MHz."""
    o = options
    out = BringupReport()
    if clock_hz is None:
        clock_hz = float(getattr(getattr(chip.transport, "model", None), "clock_hz", 8_000_000))

    def done(step: StepResult) -> StepResult:
        out.steps.append(step)
        report(step)
        return step

    # 1 -------------------------------------------------------------------------- reset
    announce("reset check (AN-706 4.4.1)")
    try:
        status, seen = reset_with_statuses(chip)
    except ResetError as exc:
        # name the wire, not only the bytes: the wiring check moves nothing (lm629_host.wiring)
        wires = wiring_suspects(chip)
        done(StepResult("reset", False, f"status bytes seen: {_hex(exc.statuses)}",
                        [f"wiring check: {w}" for w in wires] + [str(exc)],
                        {"statuses": list(exc.statuses), "wiring": wires}))
        return out
    expected = "00, 84/C4, 80/C0" if chip.uses_reset_line else "84/C4, 80/C0"
    done(StepResult("reset", True, f"status bytes seen: {_hex(seen)} (expected {expected})",
                    data={"statuses": seen, "status": int(status)}))

    if not confirm("The motor will now turn (a slow move at kp = 1). Is the shaft free to turn?"):
        done(StepResult("phasing", None, "skipped at your request: nothing moved"))
        return out

    with stop_on_error(chip):
        # 2 ---------------------------------------------------------------------- phasing
        announce(f"loop phasing at kp = {o.phasing_kp} (AN-706 2.12)")
        chip.load_filter(kp=o.phasing_kp, ki=0, kd=0, il=0)
        chip.update_filter()
        start = chip.snapshot()
        chip.load_trajectory(acceleration=o.phasing_acceleration, velocity=o.phasing_velocity,
                             position=o.phasing_distance, position_relative=True, start=True)
        t_end = start.time + o.phasing_time_s
        snap = start
        trail = [start]  # the last 50 ms: where is the shaft heading now?
        while chip.clock.now() < t_end:
            chip.clock.sleep(o.poll_s)
            snap = chip.snapshot()
            trail.append(snap)
            while trail[0].time < snap.time - 0.05:
                trail.pop(0)
            if snap.real_position - start.real_position < -10 * o.runaway_counts:
                break  # running away: no need to watch any longer
        moved = snap.real_position - start.real_position
        wanted = snap.desired_position - start.desired_position
        heading = snap.real_position - trail[0].real_position
        data = {"desired_moved": wanted, "real_moved": moved, "last_50ms": heading,
                "seconds": round(snap.time - start.time, 4)}
        # Reversed leads: the shaft goes backwards ever faster.  A load (gravity) also pulls it
        # back at first, but as the error grows the loop wins and the shaft turns forwards.
        if moved < -o.runaway_counts and heading < 0:
            _ok, note = emergency_stop(chip)
            done(StepResult(
                "phasing", False,
                f"RUNAWAY: desired went {wanted:+d} counts, the shaft went {moved:+d}: the loop "
                "pushes the wrong way. Swap the motor leads (or the encoder's A and B channels); "
                "if a load pulls the shaft back (gravity on an arm), support it and run this again",
                [note], data))
            return out
        if moved < 2 and heading <= 0:
            _ok, note = emergency_stop(chip)
            done(StepResult(
                "phasing", False,
                f"the shaft did not turn: desired went {wanted:+d} counts, the shaft {moved:+d}. "
                "Check the amplifier's supply, the PWM/sign (or DAC) wiring to it, the motor and "
                "the encoder connection", [note], data))
            return out
        sagged = " (a load pulled it back first; the loop is winning)" if moved < 2 else ""
        done(StepResult("phasing", True,
                        f"the shaft follows: desired {wanted:+d}, shaft {moved:+d} counts in "
                        f"{snap.time - start.time:.2f} s{sagged}", data=data))

        # 3 ---------------------------------------------------------------------- hold
        announce(f"hold at kp = {o.hold_kp}")
        chip.load_trajectory(stop="abrupt", start=True)
        chip.load_filter(kp=o.hold_kp)
        chip.update_filter()
        chip.clock.sleep(o.hold_time_s)
        a = chip.snapshot()
        chip.clock.sleep(0.1)
        b = chip.snapshot()
        err = b.following_error
        data = {"following_error": err, "drift": b.real_position - a.real_position,
                "dead_band": o.dead_band}
        if abs(err) > o.dead_band or b.real_position != a.real_position:
            _ok, note = emergency_stop(chip)
            if b.real_position != a.real_position:
                hint = "the shaft is still moving: an oscillation (lower kp or add kd)"
            else:
                hint = ("a steady error beyond the dead band: a load torque or friction holds "
                        "the shaft off (add ki with a small il)")
            done(StepResult(
                "hold", False,
                f"does not hold: error {err:+d} counts (dead band +/-{o.dead_band}), moved "
                f"{b.real_position - a.real_position:+d} counts in 0.1 s: {hint}", [note], data))
            return out
        done(StepResult("hold", True, f"holds {err:+d} counts from the desired position "
                                      f"(dead band +/-{o.dead_band})", data=data))

        # 4 ---------------------------------------------------------------------- move
        announce(f"small move: {o.move_distance:+d} counts")
        origin = b.desired_position
        target = origin + o.move_distance
        ramp_s, move_s = Scale(1, clock_hz).profile_times(abs(o.move_distance), o.move_velocity,
                                                          o.move_acceleration)
        # absolute: a relative position counts from the last target (the phasing move's), not
        # from where the abrupt stop left it.  move_to clears trajectory complete in the program
        # that starts the move, so only this move's completion ends the wait below
        move = chip.move_to(target, velocity=o.move_velocity, acceleration=o.move_acceleration)
        t0 = move.t0
        worst = 0
        deadline = t0 + move_s + o.settle_timeout_s
        while True:
            chip.clock.sleep(o.poll_s)
            s = chip.snapshot()
            if abs(s.following_error) > abs(worst):
                worst = s.following_error
            if s.status & Status.TRAJECTORY_COMPLETE:
                break
            if s.time > deadline:
                _ok, note = emergency_stop(chip)
                done(StepResult("move", False,
                                f"the move did not complete in {move_s + o.settle_timeout_s:.2f} s "
                                f"(profile {move_s:.2f} s); the shaft is at "
                                f"{s.real_position - origin:+d} counts", [note]))
                return out
        t_done = s.time
        data = {"seconds": round(t_done - t0, 4), "profile_s": round(move_s, 4),
                "ramp_s": round(ramp_s, 4)}
        done(StepResult("move", True,
                        f"trajectory complete after {t_done - t0:.3f} s (profile {move_s:.3f} s, "
                        f"ramps {ramp_s:.3f} s)", data=data))

        # 5 ---------------------------------------------------------------------- settle
        announce("following error and settle time")
        settled_at = None
        quiet = 0
        while s.time < t_done + o.settle_timeout_s:
            chip.clock.sleep(o.poll_s)
            s = chip.snapshot()
            inside = abs(target - s.real_position) <= o.dead_band and s.real_velocity == 0
            if inside:
                if quiet == 0:
                    settled_at = s.time
                quiet += 1
                if quiet >= 25:  # 50 ms still
                    break
            else:
                quiet = 0
                settled_at = None
        final = target - s.real_position
        result: dict[str, object] = {"max_following_error": worst, "final_error": final,
                                     "dead_band": o.dead_band,
                                     "settle_s": None if settled_at is None
                                     else round(settled_at - t_done, 4)}
        if settled_at is None or quiet < 25:
            _ok, note = emergency_stop(chip)
            done(StepResult("settle", False,
                            f"did not settle within +/-{o.dead_band} counts in "
                            f"{o.settle_timeout_s:g} s (error now {final:+d}, largest following "
                            f"error {worst:+d}): add kd for damping, or lower kp", [note], result))
            return out
        done(StepResult("settle", True,
                        f"largest following error {worst:+d} counts; settled "
                        f"{settled_at - t_done:.3f} s after the trajectory ended, "
                        f"{final:+d} counts from the target", data=result))

    # 6 -------------------------------------------------------------------------- next steps
    done(StepResult("next", None, "the loop works; now tune it", [
        "watch desired and actual position of a step:  lm629 step 200 --kp 20 --kd 100",
        "raise kd until the overshoot is gone, then kp for stiffness (AN-868 'Tuning the PID')",
        "add ki with a small il when a load leaves a steady error",
        "set a following-error limit that stops the motor:  lm629 limit 2000 --stop",
        f"the motor is left holding position at kp = {o.hold_kp}"]))
    return out


__all__ = ["BringupOptions", "BringupReport", "StepResult", "run_bringup", "reset_with_statuses",
           "EXIT_CHECK_FAILED", "EXIT_RESET_FAILED"]
