"""Arithmetic of the servo loop, with no I/O: the PID filter, the motor and load,
trajectory planning, the soft limits and the user's units (encoder lines, clock, 16.16 words)."""
