"""The sample loop again, flattened into one function of local variables, for speed.

Every test waits on the model, and a move at 8 MHz is 3906 samples per simulated second.
:meth:`.motion.Motion.sample` (with :mod:`.trajectory`, :mod:`lm629_host.physics.pid`, :mod:`.motor` and
``ChipModel._sample``) is the readable source of truth; this function computes exactly the
same thing, bit for bit and float for float, without attribute look-ups, enum arithmetic or
calls on the common path.  ``tests/sim/test_model_fastloop.py`` runs both side by side over
moves, stops, wraparound, index and LPES and compares every register at every sample.

It runs only in the steady state: no UDF in flight, no reset.  It stops early (returning the
number of samples it ran) when the chip must act (LPES turns the motor off) or when the chip
may have become quiescent (so that the caller can skip ahead).
"""

from __future__ import annotations

from collections.abc import Callable
from math import floor, log

# plain ints of the opcodes.py bits (IntFlag arithmetic is slow); _fastloop.c reads the same
# Status bits from lm629_host.bus.opcodes when it is imported
from lm629_host.bus.bits import (
    STATUS_TRAJECTORY_COMPLETE as _COMPLETE,
    STATUS_INDEX_PULSE as _INDEX,
    STATUS_WRAPAROUND as _WRAP,
    STATUS_POSITION_ERROR as _PERR,
    STATUS_BREAKPOINT as _BP,
    SIGNALS_ACQUIRE_INDEX as _ACQUIRE_INDEX,
    SIGNALS_EIGHT_BIT_OUTPUT as _EIGHT_BIT,
    SIGNALS_STOP_ON_ERROR as _STOP_ON_ERROR,
)
from lm629_host.physics.pid import SUM_MAX, SUM_MIN, full_scale, output_shift
from lm629_host.sim.model.registers import ChipState
from lm629_host.sim.model.trajectory import HALF, SPAN, landing_velocity, stop_distance

#: the output stage's shift and full-scale code, by 12-bit mode (pid's, looked up once: a call
#: each per sample was a tenth of this wrapper's cost)
_SHIFT = {twelve: output_shift(twelve) for twelve in (False, True)}
_FULL_SCALE = {twelve: full_scale(twelve) for twelve in (False, True)}


INT_ARGS = ("n kp ki kd il ds shift stall cpr index_k count home out p v a vmax target done "
            "vmode fwd stopping esum elast dterm countdown iterm u motor_off bp threshold "
            "stop_on_error flags armed rp rv").split()
FLOAT_ARGS = "volts_per_code apv load coul rate decay gain ts angle speed".split()
RESULTS = ("ran lpes_trip index_hit index_pos count out p v done esum elast dterm countdown "
           "iterm u flags rp rv angle speed").split()


def run_fast(chip: ChipState, n: int, loop: Callable[..., tuple] | None = None) -> int:
    """Run up to ``n`` samples with ``loop`` (:func:`py_loop` or the C one); return how many ran."""
    m = chip.motion
    motor, t, pid = m.motor, m.traj, m.pid
    mp = motor.params
    f = chip.filter
    signals = int(chip.signals_extra)
    twelve = not signals & _EIGHT_BIT
    cpr = motor.counts_per_rev
    # (the model's own bools go in as they are: a bool is an int to both loops)
    ints = (n, f.kp, f.ki, f.kd, f.il, f.ds, _SHIFT[twelve], int(mp.stall), cpr,
            motor.index_k, m.encoder_count, m.home_count, m.output,
            t.position, t.velocity, t.acceleration, t.max_velocity, t.target, t.done,
            t.velocity_mode, t.forward, t.stopping,
            pid.error_sum, pid.last_error, pid.derivative, pid.countdown, pid.integral, pid.output,
            chip.motor_off, chip.breakpoint, chip.position_error_threshold,
            signals & _STOP_ON_ERROR, int(chip.flags), signals & _ACQUIRE_INDEX,
            m.real_position, m.real_velocity)
    floats = (mp.amp_volts / _FULL_SCALE[twelve], motor.accel_per_volt, motor.load_accel,
              motor.coulomb_accel, motor.rate, motor.decay, motor.gain, motor.sample_s,
              motor.angle, motor.speed)
    (ran, lpes_trip, index_hit, index_pos, m.encoder_count, m.output, t.position, t.velocity, done,
     pid.error_sum, pid.last_error, pid.derivative, pid.countdown, pid.integral, pid.output,
     flags, m.real_position, m.real_velocity, motor.angle, motor.speed) = (loop or py_loop)(ints, floats)
    t.done = bool(done)
    chip.flags = flags
    if index_hit:
        m.index_position = index_pos
        chip.signals_extra = int(chip.signals_extra) & ~_ACQUIRE_INDEX
    if lpes_trip:
        chip.turn_motor_off()  # raises trajectory complete (as ChipModel._sample)
    return ran


def py_loop(ints: tuple, floats: tuple) -> tuple:
    """The loop itself: plain ints and floats in, plain ints and floats out."""
    (n, kp, ki, kd, il, ds, shift, stall, cpr, index_k, count, home, out, p, v, a, vmax, target,
     done, vmode, fwd, stopping, esum, elast, dterm, countdown, iterm, u, motor_off, bp,
     threshold, stop_on_error, flags, armed, rp, rv) = ints
    volts_per_code, apv, load, coul, rate, decay, gain, ts, angle, speed = floats
    ran = 0
    lpes_trip = 0
    index_hit = index_pos = 0
    while ran < n:
        ran += 1
        events = 0
        # ---- motor (Motor.run)
        if stall:
            speed = 0.0
        else:
            drive = out * volts_per_code * apv - load
            moving = True
            if speed == 0.0:
                if -coul <= drive <= coul:
                    moving = False
                else:
                    force = drive - coul if drive > 0 else drive + coul
            else:
                force = drive - coul if speed > 0 else drive + coul
            if moving:
                w_inf = force / rate
                w1 = w_inf + (speed - w_inf) * decay
                if speed != 0.0 and (w1 > 0) != (speed > 0):
                    t0 = -log(-w_inf / (speed - w_inf)) / rate
                    angle += w_inf * t0 + speed / rate
                    speed = 0.0
                else:
                    angle += w_inf * ts + (speed - w_inf) * gain
                    speed = w1
        # ---- encoder
        c1 = floor(angle)
        rv = c1 - count
        rp = ((c1 - home + 0x40000000) & 0x7FFFFFFF) - 0x40000000
        if armed:
            if c1 >= count:
                k = count + (index_k - count) % cpr
                hit = k <= c1
            else:
                k = count - (count - index_k) % cpr
                hit = k >= c1
            if hit:
                index_pos = ((k - home + 0x40000000) & 0x7FFFFFFF) - 0x40000000
                index_hit = 1
                armed = 0
                events |= _INDEX
        count = c1
        before = p >> 16
        if motor_off:
            p = rp << 16
            v = 0
            out = 0
        else:
            # ---- trajectory generator (Trajectory.step)
            if not done:
                if vmode or stopping:
                    goal = 0 if stopping else (vmax if fwd else -vmax)
                    if v < goal:
                        v = v + a if v + a < goal else goal
                    else:
                        v = v - a if v - a > goal else goal
                    p += v
                    if stopping and v == 0:
                        done = 1
                        events |= _COMPLETE
                else:
                    r = (((target << 16) - p + HALF) % SPAN) - HALF
                    if v == 0 and r == 0:
                        done = 1
                        events |= _COMPLETE
                    else:
                        sign = (1 if v > 0 else -1) if v else (1 if r > 0 else -1)
                        ahead, spd = r * sign, v * sign
                        if ahead <= 0:
                            spd = spd - a if spd > a else 0
                            v = spd * sign
                            p += v
                        else:
                            if spd <= vmax:
                                up = spd + a if spd + a < vmax else vmax
                            else:
                                up = spd - a if spd - a > vmax else vmax
                            if a == 0:
                                up = spd
                            elif up + (0 if up <= a else stop_distance(up, a)) > ahead:
                                up = landing_velocity(ahead, a)
                                if up < spd - a:
                                    up = spd - a
                            if up >= ahead and spd - a <= ahead:
                                v = 0
                                p += ahead * sign
                                done = 1
                                events |= _COMPLETE
                            else:
                                v = up * sign
                                p += v
                if not -HALF <= p < HALF:
                    p = ((p + HALF) % SPAN) - HALF
                    events |= _WRAP
            # ---- PID (pid_step)
            e = (((p >> 16) - rp + 0x40000000) & 0x7FFFFFFF) - 0x40000000
            e = 32767 if e > 32767 else (-32768 if e < -32768 else e)
            total = esum + e
            total = SUM_MAX if total > SUM_MAX else (SUM_MIN if total < SUM_MIN else total)
            held = ki * (esum >> 8)
            if (held >= il or held <= -il) and abs(total) > abs(esum):
                total = esum
            term = ki * (total >> 8)
            esum = total
            iterm = il if term > il else (-il if term < -il else term)
            if countdown == 0:
                d = e - elast
                d = 32767 if d > 32767 else (-32768 if d < -32768 else d)
                d *= kd
                dterm = 32767 if d > 32767 else (-32768 if d < -32768 else d)
                elast = e
                countdown = ds - 1
            else:
                countdown -= 1
            u = kp * e
            u = 32767 if u > 32767 else (-32768 if u < -32768 else u)
            u += iterm + dterm
            u = 32767 if u > 32767 else (-32768 if u < -32768 else u)
            out = u >> shift
        # ---- the chip's own events (ChipModel._sample)
        after = p >> 16
        step = ((after - before + 0x40000000) & 0x7FFFFFFF) - 0x40000000
        to_bp = ((bp - before + 0x40000000) & 0x7FFFFFFF) - 0x40000000
        if 0 <= to_bp <= step or step <= to_bp <= 0:
            events |= _BP
        if not motor_off:
            err = ((after - rp + 0x40000000) & 0x7FFFFFFF) - 0x40000000
            if err > threshold or -err > threshold:
                events |= _PERR
                if stop_on_error:
                    lpes_trip = 1
        flags |= events
        if lpes_trip:
            break
        if speed == 0.0 and rv == 0 and v == 0 and (motor_off or (
                done and dterm == 0 and elast == e and (e == 0 or ki == 0))):
            # perhaps quiescent (Motion.quiescent decides): let the caller skip ahead
            if stall or -coul <= out * volts_per_code * apv - load <= coul:
                break
    return (ran, lpes_trip, index_hit, index_pos, count, out, p, v, done, esum, elast, dterm,
            countdown, iterm, u, flags, rp, rv, angle, speed)
