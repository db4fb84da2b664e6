"""What the chip does at each sample tick: trajectory generator, PID filter, output, motor, encoder.

Contract with :class:`~.chip.ChipModel` (the host interface), which owns this object as
``chip.motion`` and calls:

* ``reset()`` on any reset: every register 0, drive off;
* ``start(trajectory) -> bool`` on STT with the LTRJ input buffer (:class:`~.chip.TrajectoryBuffer`,
  its ``loaded`` bits say which parameters were loaded since the last STT, and how); return
  False to refuse it with a command error (acceleration changed while moving with the drive on,
  negative relative velocity).  The chip then clears or sets its motor-off bit;
* ``define_home()`` (DFH), ``arm_index()`` (SIP), ``filter_changed()`` (after UDF, the new
  coefficients are in ``chip.filter``), ``drive_off()`` (motor off by LTRJ bit 8 or LPES);
* ``sample() -> int`` once per sample: advance everything by one sample and return the status
  bits this sample raised among TRAJECTORY_COMPLETE, INDEX_PULSE, WRAPAROUND (the chip adds
  BREAKPOINT and POSITION_ERROR itself from the positions below);

and reads the registers ``desired_position``, ``real_position``, ``index_position`` (signed
counts), ``desired_velocity`` (signed 16.16), ``real_velocity`` (counts/sample),
``integration_sum``, ``target_position`` (for SBPR), and the flags ``on_target``,
``velocity_mode``, ``forward``.

This first version holds the motor still: it keeps the registers and the on-target flag, so
that the host interface can be exercised; the motion issue replaces it with the real dynamics.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..opcodes import TrajectoryFlags

if TYPE_CHECKING:
    from .chip import ChipModel, TrajectoryBuffer
    from .params import MotorParams


class Motion:
    def __init__(self, chip: ChipModel, params: MotorParams) -> None:
        self.chip = chip
        self.params = params
        self.reset()

    def reset(self) -> None:
        self.desired_position = 0
        self.real_position = 0
        self.index_position = 0
        self.desired_velocity = 0
        self.real_velocity = 0
        self.integration_sum = 0
        self.target_position = 0
        self.on_target = False
        self.velocity_mode = False
        self.forward = False

    def start(self, trajectory: TrajectoryBuffer) -> bool:
        control = trajectory.control
        self.velocity_mode = bool(control & TrajectoryFlags.VELOCITY_MODE)
        self.forward = bool(control & TrajectoryFlags.FORWARD)
        if trajectory.loaded & TrajectoryFlags.POSITION:
            if trajectory.loaded & TrajectoryFlags.POSITION_RELATIVE:
                self.target_position += trajectory.position
            else:
                self.target_position = trajectory.position
        self.on_target = False
        return True

    def define_home(self) -> None:
        self.target_position -= self.desired_position
        self.desired_position = 0
        self.real_position = 0

    def arm_index(self) -> None:
        pass

    def filter_changed(self) -> None:
        pass

    def drive_off(self) -> None:
        pass

    def sample(self) -> int:
        return 0
