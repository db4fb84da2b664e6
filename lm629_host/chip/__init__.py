"""The typed command layer: :class:`LM629` and what its methods return (moves, shaped
moves, waits, recordings, batches), the soft limits every trajectory passes, positions
past the register's wraparound, supervised velocity runs, and stopping."""
