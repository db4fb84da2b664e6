"""Everything simulated, in one place: the chip model (:mod:`.model`), its clock and its
configuration from a URL (:mod:`.clock`, :mod:`.build`), the bridge's far end in Python
(:mod:`.bridge`), the compiled firmware in simavr (:mod:`.avr`), the emulated FT232H
(:mod:`.ftdi`), a lossy link for the fault tests (:mod:`.faults`) and ``lm629 sim serve``
(:mod:`.serve`).

The driver never imports this package: the simulator transports (``sim://``, ``sim+emu://``,
``sim+avr://``, ``sim+ftdi://`` in :mod:`lm629_host.transports`) reach it when such a URL is
opened, and ``lm629 sim serve`` when it runs.
"""
