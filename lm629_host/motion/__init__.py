"""Several axes on one bus (:class:`Board`: synchronized starts, straight lines, one
reset) and the bench profile that names a board's axes, their gains and limits."""
