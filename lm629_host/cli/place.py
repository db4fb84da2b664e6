"""``lm629 --place NAME``: a labgrid place acquired for one command (docs/testing.md).

Apart from :mod:`.lab` (the ``lab`` commands, which import the ``main`` group) so that the
group's own option can use it without an import circle."""

from __future__ import annotations

import click

from lm629_host.chip.safety import StopSignals
from lm629_host.integrations import labgrid_place
from lm629_host.urls import PortURL


def open_place(ctx: click.Context, text: str, signals: StopSignals) -> PortURL:
    """Acquire the place ``text`` names (``NAME`` or ``NAME?options``) and return its port's
    URL; its release is tied to ``ctx``'s close, registered before anything is acquired (so a
    Ctrl-C in between releases it too).  Stop signals are raised as exceptions from here on,
    so that SIGTERM also ends through the release."""
    try:
        name, options = labgrid_place.split_place(text)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--place") from None
    labgrid_place.client()  # labgrid missing: one line, before anything
    signals.install()
    ctx.call_on_close(signals.restore)
    ctx.call_on_close(lambda: labgrid_place.release(name))
    labgrid_place.acquire(name)
    return labgrid_place.serial_port(name).url(options)
