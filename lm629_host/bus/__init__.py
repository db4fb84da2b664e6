"""The LM629's host bus as facts: the command codes, status and signal bits, the DIP
pins, the bus programs every transport carries, and the snapshot program.  The bottom
layer: it imports nothing of the package but its errors."""
