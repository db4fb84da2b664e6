"""The bits of :mod:`.opcodes`'s registers as plain ints, derived from its flags (never typed
again): one name per bit, prefixed with its register (``STATUS_``, ``SIGNALS_``, ``TRAJ_``).

Why: an IntFlag's ``&`` and ``|`` are Python-level calls, and the paths that test these bits
run on every bus strobe or every sample (the chip model's strobes and sample loop, a wait's
snapshots, the position tracker): they test plain ints.  Each module imports the names it
tests; the flags stay the API (``Status.MOTOR_OFF``) everywhere else.
"""

from __future__ import annotations

from lm629_host.bus.opcodes import BUSY_BIT, INTERRUPTS, STOP_FLAGS, Signals, Status, TrajectoryFlags

# the status byte (RDSTAT)
STATUS_BUSY = BUSY_BIT
STATUS_COMMAND_ERROR = int(Status.COMMAND_ERROR)
STATUS_TRAJECTORY_COMPLETE = int(Status.TRAJECTORY_COMPLETE)
STATUS_INDEX_PULSE = int(Status.INDEX_PULSE)
STATUS_WRAPAROUND = int(Status.WRAPAROUND)
STATUS_POSITION_ERROR = int(Status.POSITION_ERROR)
STATUS_BREAKPOINT = int(Status.BREAKPOINT)
STATUS_MOTOR_OFF = int(Status.MOTOR_OFF)
STATUS_INTERRUPTS = int(INTERRUPTS)  #: the six interrupt conditions (MSKI, RSTI)

# the signals register (RDSIGS)
SIGNALS_ACQUIRE_INDEX = int(Signals.ACQUIRE_INDEX)
SIGNALS_MOTOR_OFF = int(Signals.MOTOR_OFF)
SIGNALS_EIGHT_BIT_OUTPUT = int(Signals.EIGHT_BIT_OUTPUT)
SIGNALS_STOP_ON_ERROR = int(Signals.STOP_ON_ERROR)
SIGNALS_ON_TARGET = int(Signals.ON_TARGET)
SIGNALS_VELOCITY_MODE = int(Signals.VELOCITY_MODE)
SIGNALS_FORWARD = int(Signals.FORWARD)
SIGNALS_FILTER_UPDATED = int(Signals.FILTER_UPDATED)
SIGNALS_ACCELERATION_LOADED = int(Signals.ACCELERATION_LOADED)
SIGNALS_HOST_INTERRUPT = int(Signals.HOST_INTERRUPT)

# the LTRJ control word
TRAJ_POSITION_RELATIVE = int(TrajectoryFlags.POSITION_RELATIVE)
TRAJ_POSITION = int(TrajectoryFlags.POSITION)
TRAJ_VELOCITY_RELATIVE = int(TrajectoryFlags.VELOCITY_RELATIVE)
TRAJ_VELOCITY = int(TrajectoryFlags.VELOCITY)
TRAJ_ACCELERATION_RELATIVE = int(TrajectoryFlags.ACCELERATION_RELATIVE)
TRAJ_ACCELERATION = int(TrajectoryFlags.ACCELERATION)
TRAJ_MOTOR_OFF = int(TrajectoryFlags.MOTOR_OFF)
TRAJ_STOP_ABRUPT = int(TrajectoryFlags.STOP_ABRUPT)
TRAJ_STOP_SMOOTH = int(TrajectoryFlags.STOP_SMOOTH)
TRAJ_VELOCITY_MODE = int(TrajectoryFlags.VELOCITY_MODE)
TRAJ_FORWARD = int(TrajectoryFlags.FORWARD)
TRAJ_STOP_FLAGS = int(STOP_FLAGS)  #: any of the three stops
