"""The serial bridge's shared facts: the link protocol (:mod:`.protocol`) and the pin map
(:mod:`.pins`), written into the firmware's ``lm629_tables.h`` by ``tools/gen_tables.py`` so
that host and firmware never keep two copies.  The transport is
:mod:`lm629_host.transports.link`; the firmware is ``firmware_bridge/`` (its image ships in
:mod:`lm629_host.data`)."""
