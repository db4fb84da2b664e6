"""``lm629 bridge list|flash``: find the serial bridge boards and flash the firmware that
ships with this package onto them (avrdude, through the board's USB bootloader)."""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

import click

from lm629_host.cli.app import main
from lm629_host.data import firmware_image

#: the image shipped inside the package (``make -C firmware_bridge bundle`` made it)
DEFAULT_HEX = firmware_image()


@dataclass(frozen=True)
class Bootloader:
    """avrdude settings of one board's bootloader."""

    name: str
    part: str
    programmer: str
    baud: int
    note: str


BOARDS = {
    "uno": Bootloader("Arduino Uno (optiboot)", "atmega328p", "arduino", 115200,
                      "the Uno's USB chip resets the board when avrdude opens the port"),
    "nano": Bootloader("Arduino Nano (new bootloader, optiboot)", "atmega328p", "arduino", 115200,
                       "Nanos sold since 2018 (and most clones flashed recently)"),
    "nano-old": Bootloader("Arduino Nano (old bootloader)", "atmega328p", "arduino", 57600,
                           "older Nanos and many CH340 clones: try this when 'nano' says "
                           "'not in sync'"),
}


def avrdude_command(port: str, hex_file: Path, board: str = "uno", avrdude: str = "avrdude",
                    verbose: bool = False) -> list[str]:
    """The avrdude command line that writes ``hex_file`` through the board's bootloader."""
    b = BOARDS[board]
    cmd = [avrdude, "-p", b.part, "-c", b.programmer, "-P", port, "-b", str(b.baud), "-D",
           "-U", f"flash:w:{hex_file}:i"]
    if verbose:
        cmd.insert(1, "-v")
    return cmd


@main.group(help="The serial bridge (an Arduino Uno/Nano running firmware_bridge).")
def bridge() -> None:
    pass


@bridge.command("list")
@click.option("--no-probe", is_flag=True, help="Only list the ports, do not send HELLO.")
@click.option("--boot", type=click.FloatRange(0, 30), default=2.5, show_default=True,
              help="Seconds to wait for a board that resets on open.")
def list_cmd(no_probe: bool, boot: float) -> None:
    """Find serial ports of usual bridge boards (Arduino Uno/Nano, CH340, FTDI) and probe
    each with the bridge handshake."""
    from lm629_host.transports.serial import KNOWN_USB_IDS, list_ports

    ports = list_ports(probe=not no_probe, boot_s=boot)
    if not ports:
        ids = ", ".join(f"{v:04X}:{p:04X}" for v, p in KNOWN_USB_IDS)
        click.echo(f"no bridge candidates found (USB ids looked for: {ids}).\n"
                   "Is the board plugged in? `lsusb` shows it; a simulated bridge is "
                   "`lm629 sim serve --pty /tmp/lm629`.")
        return
    for p in ports:
        mark = "ok " if p.usable else "-- "
        click.echo(f"{mark}{p.url}  {p.description}")
        if p.problem:
            click.echo(f"     {p.problem}")


@bridge.command("flash")
@click.option("--port", "-p", required=True, help="Serial port of the board (/dev/ttyACM0).")
@click.option("--board", type=click.Choice(sorted(BOARDS)), default="uno", show_default=True,
              help="Which bootloader: uno, nano, or nano-old (57600 baud).")
@click.option("--hex", "hex_file", type=click.Path(dir_okay=False, path_type=Path),
              default=DEFAULT_HEX, show_default=True, help="Firmware image (Intel hex).")
@click.option("--avrdude", default="avrdude", show_default=True, help="avrdude executable.")
@click.option("--dry-run", is_flag=True, help="Print the avrdude command, do not run it.")
@click.option("--verbose", "-v", is_flag=True, help="Let avrdude say what it does.")
def flash_cmd(port: str, board: str, hex_file: Path, avrdude: str, dry_run: bool,
              verbose: bool) -> None:
    """Write the bridge firmware to an Uno or Nano through its USB bootloader (avrdude).

    No programmer hardware is needed: the board's bootloader takes the image over the same
    USB cable.  Close every program that holds the port first (serial monitor, Arduino IDE).
    """
    from lm629_host.transports.serial import device_of

    dev = device_of(port)
    cmd = avrdude_command(dev, hex_file, board, avrdude, verbose)
    if dry_run:
        click.echo(" ".join(cmd))
        return
    if not hex_file.is_file():
        raise click.ClickException(
            f"no firmware image at {hex_file}: leave --hex out to flash the image shipped "
            "with this package, or build one in a checkout with `make -C firmware_bridge` "
            "(needs: sudo apt-get install gcc-avr avr-libc binutils-avr).")
    exe = shutil.which(avrdude)
    if exe is None:
        raise click.ClickException(
            f"{avrdude!r} not found: avrdude is the program that writes firmware to AVR chips. "
            "Install it with: sudo apt-get install avrdude  (then run this command again).")
    b = BOARDS[board]
    click.echo(f"flashing {hex_file.name} to {b.name} on {dev} at {b.baud} baud ({b.note})")
    r = subprocess.run(cmd)
    if r.returncode != 0:
        hint = ("'not in sync' or 'programmer is not responding' usually means the wrong "
                "bootloader speed: try --board nano-old (57600) for an older Nano, --board "
                "nano/uno (115200) otherwise; also check that no other program holds the port "
                "and that --port is the board (lm629 bridge list).")
        raise click.ClickException(f"avrdude failed (exit {r.returncode}). {hint}")
    click.echo(f"done. Check it with: lm629 bridge list   (or lm629 --port {dev} status)")
