"""``--profile FILE`` in the session: the global options a profile gives, and what is done
once the board is open (limits, names, the profile applied to a chip that lost it).

The group in :mod:`.app` calls these directly; they see the session through
:class:`ProfiledSession`, the few fields they read, so :mod:`.app` imports this module and
not the other way round (the ``profile`` commands, which need the group, are in
:mod:`.profile`).
"""

from __future__ import annotations

import logging
import os
from typing import Protocol

import click

from lm629_host.chip.lm629 import LM629
from lm629_host.config.profile import Profile, ensure_applied, load_profile, name_axes
from lm629_host.errors import BusyTimeout, ResetError
from lm629_host.motion.board import Board
from lm629_host.transports.ports import profile_port, twin_port
from lm629_host.urls import PortURL, port_url


class ProfiledSession(Protocol):
    """What of the CLI's session (:class:`lm629_host.cli.app.Session`) a profile reads."""

    profile: Profile | None
    axis_spec: tuple[int, ...] | str | None
    prepare: bool
    reapply: bool

    @property
    def is_sim(self) -> bool: ...

log = logging.getLogger("lm629_host.cli")


def _given(ctx: click.Context, name: str) -> bool:
    return ctx.get_parameter_source(name) is click.core.ParameterSource.COMMANDLINE


def profile_options(ctx: click.Context, path: str, port: str | PortURL | None, chip_name: str,
                    clock: str, lines: int | None, axis_text: str | None
                    ) -> tuple[Profile | None, str | PortURL | None, str, str, int | None,
                               str | None]:
    """The global options with the profile's values where the command line gives none (an
    explicit profile beats ``$LM629_PORT``); ``--axis`` names -> chip selects."""
    ctx.meta["lm629.profile_path"] = path
    if ctx.invoked_subcommand in ("sim", "bridge"):  # no board of the profile: $LM629_PROFILE
        return None, port, chip_name, clock, lines, axis_text  # set for the bench is ignored
    if not os.path.exists(path) and ctx.invoked_subcommand == "profile":
        return None, port, chip_name, clock, lines, axis_text  # `profile init` makes it
    prof = load_profile(path)
    if not _given(ctx, "port") and prof.port:
        port = profile_port(prof)
    elif port is not None:  # --port: the profile's chip and clock unless it says its own
        try:
            parsed = port_url(port)  # the one parse of --port
        except ValueError as exc:
            raise click.BadParameter(str(exc), param_hint="--port") from None
        have = parsed.query()
        add = {k: v for k, v in (("chip", prof.chip), ("clock", str(round(prof.clock_hz))))
               if k not in have and not _given(ctx, "chip_name" if k == "chip" else k)}
        port = twin_port(prof, parsed.with_options(add))
    if not _given(ctx, "chip_name"):
        chip_name = prof.chip
    if not _given(ctx, "clock"):
        clock = f"{prof.clock_hz:g}"
    named = list(prof.axes.values())
    if axis_text is not None and axis_text.strip().lower() != "all":
        named, numbers = [], []
        for word in (w.strip() for w in axis_text.split(",") if w.strip()):
            if word.isdigit():
                numbers.append(word)
                ax = prof.by_cs(int(word))
                if ax is not None:
                    named.append(ax)
            elif word in prof.axes:
                named.append(prof.axes[word])
                numbers.append(str(prof.axes[word].cs))
            else:
                raise click.BadParameter(f"{word!r} is no axis of {path} (it has "
                                         f"{', '.join(prof.axes) or 'none'}) nor a chip select",
                                         param_hint="--axis")
        axis_text = ",".join(numbers)
    elif axis_text is None and prof.axes:
        axis_text = ",".join(str(a.cs) for a in sorted(prof.axes.values(), key=lambda a: a.cs))
    if lines is None and named:
        lines = named[0].lines
    return prof, port, chip_name, clock, lines, axis_text


def _say(text: str) -> None:
    click.echo(f"lm629: {text}", err=True)


def named_axes(s: ProfiledSession, b: Board) -> dict[str, LM629]:
    """The profile's axes that the board has, by name."""
    prof = s.profile
    assert prof is not None, "called for a session with --profile"
    return {name: b.axes[ax.cs] for name, ax in prof.axes.items() if ax.cs < len(b.axes)}


def profile_opened(s: ProfiledSession, b: Board) -> None:
    """Once the board is open: each profile axis gets its limits and variant; a chip that has
    lost its settings gets the profile (one line each), unless the command says not to
    (``reset``, ``profile show``, ``profile apply``)."""
    prof = s.profile
    assert prof is not None, "called for a session with --profile"
    only = s.axis_spec if isinstance(s.axis_spec, tuple) else None  # --axis: those alone
    name_axes(b, prof, only)  # limits, variants, board["x"] in the shell
    if s.prepare and s.reapply:
        # an in-process simulator is a fresh chip for every command (and says so): applying
        # the profile to it is the rule, not news
        chips = {n: c for n, c in named_axes(s, b).items() if only is None or prof.axes[n].cs in only}
        for name, chip in chips.items():  # one at a time: an error names its axis
            try:
                ensure_applied({name: chip}, prof, log.info if s.is_sim else _say)
            except (BusyTimeout, ResetError) as exc:
                raise _on_axis(exc, name, prof) from exc


def _on_axis(exc: BusyTimeout | ResetError, name: str, prof: Profile) -> BusyTimeout | ResetError:
    """``exc`` (the same class: the same exit code) saying which axis of the profile and chip
    select it came from, and the likely fix."""
    cs = prof.axes[name].cs
    exc.args = (f"axis {name} (cs {cs}) of {prof.path} does not answer: {exc.args[0] if exc.args else exc} "
                f"Likely fix: a chip on chip select {cs} (on `lm629 sim serve`, serve the "
                f"profile's chips: --url 'sim://?axes={cs + 1}'; on a board, check the /CS wire "
                "of that chip and its power), or remove the axis from the profile",)
    return exc


__all__ = ["named_axes", "profile_opened", "profile_options"]
