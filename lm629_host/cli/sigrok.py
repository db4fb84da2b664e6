"""``lm629 sigrok install``: the package's protocol decoder where PulseView and sigrok-cli find
it (:mod:`lm629_host.sigrok`; docs/debugging.md)."""

from __future__ import annotations

from pathlib import Path

import click

from lm629_host.cli.app import main


@main.group(help="The lm629 protocol decoder for sigrok (PulseView, sigrok-cli).")
def sigrok() -> None:
    pass


@sigrok.command("install")
@click.option("--dir", "directory", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="The decoders directory to install into (default: "
                   "~/.local/share/libsigrokdecode/decoders, where PulseView and sigrok-cli look).")
def install_cmd(directory: Path | None) -> None:
    """Copy the lm629 decoder to where sigrok looks for decoders."""
    from lm629_host.sigrok import install

    try:
        target = install(directory)
    except OSError as exc:  # the directory given cannot hold it: bad usage, nothing written
        raise click.BadParameter(f"cannot install the decoder there: {exc.strerror or exc} "
                                 f"({exc.filename or directory})", param_hint="--dir") from None
    click.echo(f"installed the lm629 decoder in {target}")
    hint = "" if directory is None else f"SIGROKDECODE_DIR={target.parent} "
    click.echo(f"try: {hint}sigrok-cli -I vcd -i bus.vcd -P lm629 -A lm629=commands:warnings")
