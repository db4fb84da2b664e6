"""``lm629 sim serve``: a simulated bridge and chip on a pseudo-terminal or a TCP port, that
keeps its state between clients like a board on the bench (:mod:`lm629_host.sim.serve`)."""

from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import Any

import click

from lm629_host.cli.app import main


@main.group(help="The simulated bench.")
def sim() -> None:
    pass


#: the scheduling priority the server asks for (nice value) where it may (root, or
#: CAP_SYS_NICE): it stands for the bridge's own microcontroller, which no load on the host PC
#: slows, so CPU-burning processes beside the bench make the host late, not the board
SERVER_NICE = -10


def _far_end_priority() -> None:
    """Ask for :data:`SERVER_NICE` before any thread starts (a Linux thread takes its nice
    value from the thread that made it); where that is not allowed, keep the nice value."""
    try:
        if os.getpriority(os.PRIO_PROCESS, 0) > SERVER_NICE:
            os.setpriority(os.PRIO_PROCESS, 0, SERVER_NICE)
    except (OSError, AttributeError):  # not allowed here, or no such call on this OS
        pass


def _tcp_address(text: str) -> tuple[str, int]:
    """``PORT`` or ``HOST:PORT`` (the host defaults to 127.0.0.1: this machine only)."""
    host, _, port = text.rpartition(":")
    try:
        number = int(port)
    except ValueError:
        raise click.BadParameter(f"{text!r} is not PORT or HOST:PORT", param_hint="--tcp") from None
    if not 0 <= number <= 65535:
        raise click.BadParameter(f"port {number} is outside 0..65535", param_hint="--tcp")
    return host or "127.0.0.1", number


@sim.command("serve")
@click.option("--pty", "pty_path", type=click.Path(path_type=Path), default=None,
              help="Where to link the pseudo-terminal (e.g. /tmp/lm629).")
@click.option("--tcp", "tcp", default=None, metavar="[HOST:]PORT",
              help="Serve on a TCP port instead (0: any free one; host 127.0.0.1 unless given), "
                   "for clients on socket://HOST:PORT, as behind ser2net.")
@click.option("--firmware", is_flag=True,
              help="Run the real bridge firmware in simavr instead of the Python emulator.")
@click.option("--url", default="sim://", show_default=True,
              help="The simulated chip: sim:// parameters (chip=, clock=, record=...), and "
                   "usb=uno|ftdi|cdc (usb_seed=, latency_ms=) for a USB adapter's latency.")
def serve_cmd(pty_path: Path | None, tcp: str | None, firmware: bool, url: str) -> None:
    """Serve a simulated bridge and chip on a pseudo-terminal (or a TCP port) until Ctrl-C.

    Then, from other shells: lm629 --port serial://PATH ...   (or pyserial, a terminal).
    One client at a time (a second is refused while one is connected, as ser2net does);
    SIGUSR1 cycles the board's power: every chip as from power-on, the bridge stays up.
    """
    from lm629_host.sim.serve import SimServer

    if (pty_path is None) == (tcp is None):
        raise click.UsageError("give --pty PATH or --tcp [HOST:]PORT (one of them)")
    address = _tcp_address(tcp) if tcp is not None else None
    if pty_path is not None and not pty_path.parent.is_dir():
        raise click.BadParameter(f"{str(pty_path)!r}: the directory {str(pty_path.parent)!r} "
                                 "does not exist", param_hint="--pty")
    from lm629_host.transports.ports import resolve_port
    _far_end_priority()
    try:
        resolve_port(url)  # the board options and the axis= mistake, said as --port says them
        server = SimServer(pty_path, url, firmware=firmware, tcp=address)
    except ValueError as exc:  # a bad --url parameter (usb=, chip=, ...): a usage error
        raise click.BadParameter(str(exc), param_hint="--url") from None
    except RuntimeError as exc:
        raise click.ClickException(str(exc)) from None
    try:
        server.open()
    except (FileExistsError, ValueError, OSError) as exc:
        server.far.close()
        raise click.BadParameter(str(exc), param_hint="--tcp" if tcp else "--pty") from None
    click.echo(f"serving {server.describe()}")
    click.echo(f"connect with: lm629 --port {server.client_url} ...   (Ctrl-C stops; "
               f"`kill -USR1 {os.getpid()}` cycles the board's power)")
    signal.signal(signal.SIGTERM, lambda *_: server.stop())
    signal.signal(signal.SIGUSR1, lambda *_: server.power_cycle())
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.close()
        click.echo(f"stopped ({server.bytes_in} bytes in, {server.bytes_out} bytes out)")


def simulated_plant() -> Any:
    """The bundled simulator's motor (its default parameters) as the tuner sees a plant
    (:class:`lm629_host.bench.twin.Plant`): what ``lm629 panel`` predicts a step on
    ``sim://`` with, when no profile gives the axis a plant.  From the model's own numbers
    (:class:`lm629_host.sim.model.motor.Motor`), so that the two cannot drift apart."""
    from lm629_host.bench.twin import Plant
    from lm629_host.sim.model.motor import Motor
    from lm629_host.sim.model.params import MotorParams
    m = Motor(MotorParams(), 1.0)
    full = m.accel_per_volt * m.params.amp_volts
    return Plant(accel=full, tau=1.0 / m.rate, dry=m.coulomb_accel / full,
                 load=m.load_accel / full, reversed=m.params.reversed)
