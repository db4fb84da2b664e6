"""``lm629 panel``: the bench in a browser (:mod:`lm629_host.panel`, docs/panel.md).

The page's commands run here, in the panel's process, through the same click commands as the
command line (:func:`run_command`): the same checks, and an error is the same one line
(:func:`lm629_host.cli.app.error_line`).  The port opens once, for as long as the panel runs;
a closed tab stops nothing, and the panel's own end (Ctrl-C, SIGTERM, SIGHUP) stops a moving
axis before it exits, as every command does.
"""

from __future__ import annotations

import contextlib
import io
import signal
import threading
from typing import Any

import click

from lm629_host.chip.safety import STOP_SIGNALS, signal_exception
from lm629_host.cli.app import Session, _session, axes_of, axis_name, error_line, main, stop_note_of
from lm629_host.panel.bench import BenchWorker, Outcome, PanelStop
from lm629_host.panel.server import PanelServer, is_loopback

#: where the panel listens unless told: loopback, a port of its own ("lm629" without the lm)
DEFAULT_LISTEN = "127.0.0.1:8629"


class ListenBusy(click.ClickException):
    """The address to listen on is taken: exit 3, as a busy serial port's."""

    exit_code = 3


def parse_listen(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[::1]:PORT`` for IPv6), else click.BadParameter."""
    host, sep, port = text.strip().rpartition(":")
    host = host.strip("[]")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise click.BadParameter(f"{text!r}: HOST:PORT, such as {DEFAULT_LISTEN} (port 0: any "
                                 "free port)", param_hint="--listen")
    return host, int(port)


def run_command(session: Session, argv: list[str]) -> Outcome:
    """Run ``lm629 ARGV`` on the panel's open ``session`` (its board stays open): what it
    printed, or its one error line and exit code, as the command line would end."""
    name, args = argv[0], argv[1:]
    parent = click.Context(main, info_name="lm629", obj=session)
    out = io.StringIO()
    try:
        with contextlib.redirect_stdout(out), parent:
            cmd = main.get_command(parent, name)
            assert cmd is not None, name
            with cmd.make_context(name, list(args), parent=parent) as ctx:
                cmd.invoke(ctx)
    except PanelStop as exc:
        return Outcome(130, stop_note_of(exc, str(exc) or "stopped from the panel"))
    except click.exceptions.Exit as exc:
        return Outcome(exc.exit_code, out.getvalue().strip())
    except Exception as exc:  # noqa: BLE001 - the command line's one line and exit code
        message, code = error_line(exc)
        return Outcome(code, stop_note_of(exc, message))
    return Outcome(0, out.getvalue().strip())


def _known_gains(s: Session, axes: list[tuple[int, str]]) -> dict[int, dict[str, int]]:
    """The gains each axis has as the panel starts, where the host knows them: a profile's
    (applied when the board opened), a fresh simulated chip's kp = 20."""
    out: dict[int, dict[str, int]] = {}
    for cs, _name in axes:
        ax = s.profile.by_cs(cs) if s.profile is not None else None
        if ax is not None and ax.kp is not None:
            out[cs] = {k: v for k in ("kp", "ki", "kd", "il", "ds")
                       if (v := getattr(ax, k, None)) is not None}
        elif s.is_sim and s.prepare:
            out[cs] = {"kp": 20, "ds": 1}
    return out


@main.command()
@click.option("--listen", default=DEFAULT_LISTEN, show_default=True, metavar="HOST:PORT",
              help="Where the page is served (port 0: any free port).")
@click.option("--expose", is_flag=True,
              help="Allow --listen beyond loopback (this page moves motors): the address "
                   "printed then carries a token that every request must show.")
def panel(listen: str, expose: bool) -> None:
    """The bench in a browser: live plots, status lights, moves, stops, gains and step tests
    (docs/panel.md).  Prints the page's address on its first line; Ctrl-C ends it (a moving
    axis is stopped first)."""
    host, port = parse_listen(listen)
    if not is_loopback(host) and not expose:
        raise click.BadParameter(f"{host} reaches beyond this machine, and this page moves "
                                 "motors: add --expose to mean it (the address printed then "
                                 "carries a token), or use an SSH forward to 127.0.0.1",
                                 param_hint="--listen")
    s = _session()
    axes = [(cs, axis_name(s, cs)) for cs in axes_of(s)]
    worker = BenchWorker(s, lambda argv: run_command(s, argv), axes)
    try:
        server = PanelServer((host, port), worker, title=str(s.port))
    except OSError as exc:
        raise ListenBusy(f"cannot listen on {listen}: {exc.strerror or exc} (another panel "
                         "there? --listen 127.0.0.1:0 takes a free port); nothing was "
                         "opened") from None
    # the panel's own signal handling: the worker runs every bus program, the main thread only
    # waits, so a stop signal is raised here at once and the worker stops a moving axis
    s.signals.restore()
    old = {sig: signal.signal(sig, _raise) for sig in STOP_SIGNALS}
    serving = threading.Thread(target=server.serve_forever, name="lm629-panel-http", daemon=True)
    try:
        worker.start()
        worker.ready.wait()
        if worker.exception is not None:
            raise worker.exception
        worker.gains.update(_known_gains(s, axes))
        serving.start()
        click.echo(server.address())
        click.echo(f"serving {s.port} ({', '.join(n for _c, n in axes)}); samples: "
                   f"{worker.source}; Ctrl-C ends it", err=True)
        forever = threading.Event()
        while not forever.wait(0.5):
            if not worker.alive:
                raise worker.exception or click.ClickException("the bench stopped")
    finally:  # the worker first (a moving axis stopped, the commands answered), then the server
        worker.close()
        if serving.is_alive():
            server.drain(5.0)
            server.shutdown()
        server.server_close()
        for sig, handler in old.items():
            signal.signal(sig, handler)


def _raise(signum: int, frame: Any) -> None:
    raise signal_exception(signum)


__all__ = ["DEFAULT_LISTEN", "panel", "parse_listen", "run_command"]
