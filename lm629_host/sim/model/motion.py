"""What the chip does at each sample tick: trajectory generator, PID filter, output, motor, encoder.

Contract with :class:`~.chip.ChipModel` (the host interface), which owns this object as
``chip.motion`` and calls:

* ``reset()`` on any reset: every register 0, drive off;
* ``start(trajectory) -> bool`` on STT with the LTRJ input buffer (:class:`~.registers.TrajectoryBuffer`,
  its ``loaded`` bits say which parameters were loaded since the last STT, and how); return
  False to refuse it with a command error (acceleration changed while moving with the drive on;
  a velocity or acceleration out of 0..3FFFFFFF, which ``start`` then removes from
  ``loaded``).  The chip then clears or sets its motor-off bit;
* ``define_home()`` (DFH), ``arm_index()`` (SIP), ``filter_changed()`` (after UDF, the new
  coefficients are in ``chip.filter``), ``drive_off()`` (motor off by LTRJ bit 8 or LPES);
* ``sample() -> int`` once per sample: advance everything by one sample and return the status
  bits this sample raised among TRAJECTORY_COMPLETE, INDEX_PULSE, WRAPAROUND (the chip adds
  BREAKPOINT and POSITION_ERROR itself from the positions below);

and reads the registers ``desired_position``, ``real_position``, ``index_position`` (signed
counts), ``desired_velocity`` (signed 16.16), ``real_velocity`` (counts/sample),
``integration_sum``, ``target_position`` (for SBPR), and the flags ``on_target``,
``velocity_mode``, ``forward``.  Beyond the contract: ``output`` (the signed output word),
``dac_code``/``pwm`` (the pins), ``quiescent()`` and ``skip(n)`` (the chip's skip-ahead), and
``motor`` (:class:`~.motor.Motor`, the shaft).

Order within one sample: the motor runs for the sample period with the output word computed
at the previous sample (the output is held for the whole sample); the encoder is read; the
trajectory generator steps; the filter computes the new output from e = desired - real.

Where the datasheet and the notes are silent this module follows the model choices listed in
one place, the docstring of :mod:`lm629_host.sim.model` (``model/__init__.py``): 7-23 concern the
sample loop here, 26 the encoder.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

# plain ints of the opcodes.py bits (an IntFlag's operators are Python calls, and STT, the
# quiescence test and the index watch run per command or per sample)
from lm629_host.bus.bits import (
    TRAJ_ACCELERATION as _ACC,
    TRAJ_ACCELERATION_RELATIVE as _ACC_REL,
    TRAJ_VELOCITY as _VEL,
    TRAJ_VELOCITY_RELATIVE as _VEL_REL,
    TRAJ_POSITION as _POS,
    TRAJ_POSITION_RELATIVE as _POS_REL,
    TRAJ_MOTOR_OFF as _MOTOR_OFF,
    TRAJ_STOP_ABRUPT as _STOP_ABRUPT,
    TRAJ_STOP_SMOOTH as _STOP_SMOOTH,
    TRAJ_VELOCITY_MODE as _VELOCITY_MODE,
    TRAJ_FORWARD as _FORWARD,
    SIGNALS_EIGHT_BIT_OUTPUT as _EIGHT_BIT_OUTPUT,
    SIGNALS_ACQUIRE_INDEX as _ACQUIRE_INDEX,
)
from lm629_host.bus.opcodes import ACCELERATION_MAX, VELOCITY_MAX, Status, wrap_counts
from lm629_host.sim.model.motor import Motor
from lm629_host.physics.pid import (
    PIDState,
    full_scale,
    holds,
    lm628_dac_code,
    lm629_pwm,
    output_code,
    pid_step,
    sat16,
    skip_held,
)
from lm629_host.sim.model.registers import ChipState, TrajectoryBuffer
from lm629_host.sim.model.trajectory import Trajectory

if TYPE_CHECKING:
    from lm629_host.sim.model.params import MotorParams


class Motion:
    def __init__(self, chip: ChipState, params: MotorParams) -> None:
        self.chip = chip
        self.params = params
        self.motor = Motor(params, chip.sample_clocks / chip.clock_hz)
        self.traj = Trajectory()
        self.pid = PIDState()
        self.reset()

    # ------------------------------------------------------------------ registers
    def reset(self, position: int = 0) -> None:
        """Any reset: registers 0 (``position`` [model choice 33]), drive off.  The shaft stays
        where it is."""
        self.traj.reset()
        self.pid = PIDState()
        #: the encoder count where real position is 0, and the count at the last sample: the
        #: sample loop's state, which the flattened loop (fastloop.py) reads and writes too
        self.home_count = self.motor.count - position
        self.encoder_count = self.motor.count
        self.real_position = position
        self.real_velocity = 0
        self.index_position = 0
        self.output = 0
        self._resume = False  # a move was interrupted by motor off
        self._started = False  # no STT since reset: not "on target" (signals 01C0 after reset)
        #: an STT came too soon after the last one [model choice 34]: the next sample does not
        #: run the filter, so the output stays at the last sample's value
        self.abort_pending = False
        self.traj.position = position << 16
        self.traj.target = position

    @property
    def desired_position(self) -> int:
        return self.traj.position >> 16

    @property
    def desired_velocity(self) -> int:
        return self.traj.velocity

    @property
    def target_position(self) -> int:
        return self.traj.target

    @property
    def integration_sum(self) -> int:
        return self.pid.integral

    @property
    def on_target(self) -> bool:
        return self.traj.done and self._started and not self._resume

    @property
    def velocity_mode(self) -> bool:
        return self.traj.velocity_mode

    @property
    def forward(self) -> bool:
        return self.traj.forward

    @property
    def twelve_bit(self) -> bool:
        return not self.chip.signals_extra & _EIGHT_BIT_OUTPUT

    @property
    def dac_code(self) -> int:
        """LM628 output pins: offset binary (80 / 800 = zero drive)."""
        return lm628_dac_code(self.output, self.twelve_bit)

    @property
    def pwm(self) -> tuple[int, int]:
        """LM629 output pins: (sign, magnitude 0..128)."""
        return lm629_pwm(self.output)

    # ------------------------------------------------------------------ commands
    def start(self, trajectory: TrajectoryBuffer) -> bool:
        """STT.  False: refused (command error) and ignored [model choice 13]; a velocity or
        acceleration out of range is then dropped from ``trajectory.loaded``."""
        t = self.traj
        loaded, stop, mode = trajectory.loaded, trajectory.stop, trajectory.mode
        moving = not t.done or t.velocity != 0
        drive_on = not self.chip.motor_off
        if loaded & _ACC and moving and drive_on and not stop & _MOTOR_OFF:
            return False  # AN-706 3.3: not until completed or the drive is off [model choice 28]
        acceleration, velocity = t.acceleration, t.max_velocity
        if loaded & _ACC:
            acceleration = (acceleration + trajectory.acceleration if loaded & _ACC_REL
                            else trajectory.acceleration)
        if loaded & _VEL:
            velocity = (velocity + trajectory.velocity if loaded & _VEL_REL
                        else trajectory.velocity)
        # AN-706 6.5.1 (negative), 2.7 (30-bit range) [model choice 30]: refused, and the
        # value that came out of range counts as never loaded (6.6.6: the error is "when
        # loading" it), so that a later STT (a stop) is not refused for it [model choice 13]
        bad = 0
        if not 0 <= acceleration <= ACCELERATION_MAX:
            bad |= _ACC | _ACC_REL
        if not 0 <= velocity <= VELOCITY_MAX:
            bad |= _VEL | _VEL_REL
        if bad:
            trajectory.loaded &= ~bad
            return False
        self._started = True
        t.acceleration = acceleration
        t.max_velocity = velocity
        if self.chip.motor_off and t.done and not t.stopping:
            # AN-706 6.3.3: the last trajectory had completed (or none since reset) and the
            # motor is off: the target is where the shaft is now, so a plain STT holds it
            # there [model choice 27]
            t.target = self.real_position
        if loaded & _POS:
            t.target = wrap_counts(t.target + trajectory.position if loaded & _POS_REL
                                   else trajectory.position)
        if stop & _MOTOR_OFF:
            self._resume = self._resume or not t.done
            return True  # the chip turns the drive off
        if stop & _STOP_ABRUPT:
            t.stop_abruptly()
            return True
        if stop & _STOP_SMOOTH:
            t.stop_smoothly()
            return True
        if self.chip.motor_off:
            # closing the loop: start from where the shaft is, at rest
            t.position = self.real_position << 16
            t.velocity = 0
        # the mode of the last LTRJ without a stop bit: after a stop, the interrupted
        # trajectory's mode and direction (AN-706 6.3.1, 6.3.3) [model choice 27]
        t.velocity_mode = bool(mode & _VELOCITY_MODE)
        t.forward = bool(mode & _FORWARD)
        t.stopping = False
        t.done = False
        self._resume = False
        return True

    def define_home(self) -> None:
        self.traj.define_home()
        self.home_count = self.encoder_count
        self.real_position = 0

    def arm_index(self) -> None:
        pass  # the chip has set signals bit 0; sample() watches for the index while it is set

    def filter_changed(self) -> None:
        pass  # the coefficients are read from chip.filter at every sample

    def drive_off(self) -> None:
        t = self.traj
        if not t.done:
            self._resume = True
        t.velocity = 0
        self.output = 0
        self.pid = PIDState()

    # ------------------------------------------------------------------ the sample
    def sample(self) -> int:
        chip = self.chip
        events = 0
        motor = self.motor
        # 1. the motor runs for one sample with the output held since the last one
        motor.run(self.output * (motor.params.amp_volts / full_scale(self.twelve_bit)))
        # 2. the encoder
        c0, c1 = self.encoder_count, motor.count
        self.encoder_count = c1
        self.real_velocity = c1 - c0
        self.real_position = wrap_counts(c1 - self.home_count)
        if chip.signals_extra & _ACQUIRE_INDEX:
            k = motor.index_between(c0, c1)
            if k is not None:
                self.index_position = wrap_counts(k - self.home_count)
                chip.signals_extra &= ~_ACQUIRE_INDEX
                events |= Status.INDEX_PULSE
        t = self.traj
        if chip.motor_off:
            # 7. the desired position follows the shaft; no drive
            t.position = self.real_position << 16
            t.velocity = 0
            self.output = 0
            return events
        # 3. the trajectory generator
        finished, wrapped = t.step()
        if finished:
            events |= Status.TRAJECTORY_COMPLETE
        if wrapped:
            events |= Status.WRAPAROUND
        if self.abort_pending:
            # [model choice 34] the calculation was aborted by a new STT: the output stays
            self.abort_pending = False
            return events
        # 4. the filter
        f = chip.filter
        e = wrap_counts((t.position >> 16) - self.real_position)
        u = pid_step(self.pid, e, f.kp, f.ki, f.kd, f.il, f.ds)
        self.output = output_code(u, self.twelve_bit)
        return events

    def run_plant_only(self) -> None:
        """One sample during a reset: the shaft turns with the drive at zero, nothing else.

        The encoder's counts are kept (``encoder_count`` is not touched): the reset that follows
        makes wherever the shaft then is position 0.
        """
        self.output = 0
        self.motor.run(0.0)

    def plant_at_rest(self) -> bool:
        """The shaft is still and zero drive leaves it still (the reset window may skip)."""
        m = self.motor
        return m.speed == 0.0 and (m.params.stall or abs(m.load_accel) <= m.coulomb_accel)

    def position_error(self) -> int:
        """desired - real, as the chip compares it with the LPEI/LPES threshold."""
        return wrap_counts(self.desired_position - self.real_position)

    # ------------------------------------------------------------------ skip-ahead
    def quiescent(self) -> bool:
        """True when every further sample would leave every register as it is now.

        Then the chip may skip samples (:meth:`skip`) until the host next acts: the trajectory
        generator is idle, the shaft is stuck still, and the filter's output cannot change.
        """
        m = self.motor
        if m.speed != 0.0:
            return False
        volts = self.output * (m.params.amp_volts / full_scale(self.twelve_bit))
        if not m.params.stall and abs(volts * m.accel_per_volt - m.load_accel) > m.coulomb_accel:
            return False  # the shaft is about to break away
        if self.real_velocity:
            return False
        if self.chip.motor_off:
            return True
        t = self.traj
        if not t.done or t.velocity:
            return False
        e = sat16(wrap_counts((t.position >> 16) - self.real_position))
        return holds(self.pid, e, self.chip.filter.ki, self.chip.filter.il)

    def skip(self, n: int) -> None:
        """Advance ``n`` quiescent samples at once (only what still changes: the error sum)."""
        if self.chip.motor_off:
            return
        e = sat16(wrap_counts(self.desired_position - self.real_position))
        skip_held(self.pid, n, e, self.chip.filter.il, self.chip.filter.ds)
