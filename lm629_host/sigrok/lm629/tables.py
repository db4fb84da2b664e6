"""The LM628/LM629 facts the decoder needs, as plain literals.

The decoder runs inside libsigrokdecode's interpreter, where ``lm629_host`` is not installed,
so it carries its own copy of these numbers; ``tests/integrations/test_sigrok.py`` checks
every one of them against ``lm629_host.bus.opcodes``, the project's one definition, so that
the two cannot drift.
"""

#: opcode -> (name, direction of its data words, words: the minimum for LFIL and LTRJ)
COMMANDS = {
    0x00: ("RESET", "none", 0),
    0x01: ("STT", "none", 0),
    0x02: ("DFH", "none", 0),
    0x03: ("SIP", "none", 0),
    0x04: ("UDF", "none", 0),
    0x05: ("PORT8", "none", 0),
    0x06: ("PORT12", "none", 0),
    0x07: ("RDDV", "read", 2),
    0x08: ("RDDP", "read", 2),
    0x09: ("RDIP", "read", 2),
    0x0A: ("RDRP", "read", 2),
    0x0B: ("RDRV", "read", 1),
    0x0C: ("RDSIGS", "read", 1),
    0x0D: ("RDSUM", "read", 1),
    0x1A: ("LPES", "write", 1),
    0x1B: ("LPEI", "write", 1),
    0x1C: ("MSKI", "write", 1),
    0x1D: ("RSTI", "write", 1),
    0x1E: ("LFIL", "write", 1),
    0x1F: ("LTRJ", "write", 1),
    0x20: ("SBPA", "write", 2),
    0x21: ("SBPR", "write", 2),
}

#: the status byte, bit by bit
STATUS_BITS = (
    (0x01, "BUSY"),
    (0x02, "COMMAND_ERROR"),
    (0x04, "TRAJECTORY_COMPLETE"),
    (0x08, "INDEX_PULSE"),
    (0x10, "WRAPAROUND"),
    (0x20, "POSITION_ERROR"),
    (0x40, "BREAKPOINT"),
    (0x80, "MOTOR_OFF"),
)

#: the signals register (RDSIGS)
SIGNALS_BITS = (
    (0x0001, "ACQUIRE_INDEX"),
    (0x0002, "COMMAND_ERROR"),
    (0x0004, "TRAJECTORY_COMPLETE"),
    (0x0008, "INDEX_PULSE"),
    (0x0010, "WRAPAROUND"),
    (0x0020, "POSITION_ERROR"),
    (0x0040, "BREAKPOINT"),
    (0x0080, "MOTOR_OFF"),
    (0x0100, "EIGHT_BIT_OUTPUT"),
    (0x0200, "STOP_ON_ERROR"),
    (0x0400, "ON_TARGET"),
    (0x0800, "VELOCITY_MODE"),
    (0x1000, "FORWARD"),
    (0x2000, "FILTER_UPDATED"),
    (0x4000, "ACCELERATION_LOADED"),
    (0x8000, "HOST_INTERRUPT"),
)

#: the LTRJ control word
TRAJECTORY_BITS = (
    (0x0001, "POSITION_RELATIVE"),
    (0x0002, "POSITION"),
    (0x0004, "VELOCITY_RELATIVE"),
    (0x0008, "VELOCITY"),
    (0x0010, "ACCELERATION_RELATIVE"),
    (0x0020, "ACCELERATION"),
    (0x0100, "MOTOR_OFF"),
    (0x0200, "STOP_ABRUPT"),
    (0x0400, "STOP_SMOOTH"),
    (0x0800, "VELOCITY_MODE"),
    (0x1000, "FORWARD"),
)

#: LTRJ parameters in the order their two-word values follow the control word:
#: (flag, its relative flag, name)
TRAJECTORY_ORDER = ((0x0020, 0x0010, "acceleration"), (0x0008, 0x0004, "velocity"),
                    (0x0002, 0x0001, "position"))

#: the LFIL control word's low byte: the coefficients that follow, in this order
FILTER_BITS = ((0x08, "KP"), (0x04, "KI"), (0x02, "KD"), (0x01, "IL"))

#: the interrupt conditions MSKI enables and RSTI clears (status bits 1..6)
INTERRUPTS = 0x7E
