"""The bench's description as data: the profile file (its schema, checks and line-numbered
errors, the gains and plants saved back with their comments), read by the board, the CLI, the
pytest plugin and the simulator that builds a twin from it.  Below the simulator and the
driver: it applies itself to a chip through the chip's public commands only."""
