"""How a board is wired: the pin map of each adapter (Uno/Nano bridge, FT232H), the
connection table generated from them, the vocabulary of wiring faults and the
readings a correctly wired chip gives the wiring check."""
