"""Several axes on one bus (:class:`Board`): one reset, synchronized starts, straight-line
moves, batches over axes."""
