"""The bench and this machine: ``bringup`` (AN-706 2.12), ``list`` (the ports each
transport finds), ``doctor`` (what is installed and what is wrong), ``udev`` (the FT232H rule)."""

from __future__ import annotations

import sys

import click

import lm629_host

from lm629_host.bench.bringup import BringupOptions, StepResult, run_bringup
from lm629_host.errors import BusyTimeout, LM629Error, ResetError
from lm629_host.chip.lm629 import LM629
from lm629_host.errors import check_int
from lm629_host.bus.opcodes import Status
from lm629_host.cli.app import axis_name, log, main, Session, _session
from lm629_host.cli.common import _abort_is_interrupt, _flags, _position
from lm629_host.cli.types import FINITE


@main.command()
@click.option("--yes", "-y", is_flag=True, help="Do not ask before the motor turns (scripts).")
@click.option("--move", "move_distance", type=FINITE, default=None,
              help="The small move: counts (default 1000), revolutions with --lines.")
@click.option("--hold-kp", type=int, default=20, show_default=True, help="kp of the hold step.")
def bringup(yes: bool, move_distance: float | None, hold_kp: int) -> None:
    """The AN-706 2.12 bring-up: reset, phasing (the tuner's P-only steps), kp = 20 hold, a small move,
    following error and settle time, next steps.  A prompt ended by Ctrl-C or end of input
    exits 130 with nothing moved."""
    s = _session()
    move_distance = 1000 if move_distance is None else _position(s, move_distance, "--move")
    check_int("--move", move_distance, -100_000, 100_000)
    check_int("--hold-kp", hold_kp, 1, 0x7FFF)
    options = BringupOptions(hold_kp=hold_kp, move_distance=move_distance)
    from lm629_host.cli import axes
    if axes.several(s):  # one axis after the other; the exit code is the worst
        codes = []
        for k in axes.axes_of(s):
            s.prepare = False
            chip = axes.board(s).axis(k)
            click.echo(f"bring-up of axis {axes.axis_name(s, k)}")
            codes.append(_bringup_one(s, chip, options, yes))
        click.get_current_context().exit(max(codes))
    chip = s.open(prepare=False)
    click.get_current_context().exit(_bringup_one(s, chip, options, yes))


def _bringup_one(s: Session, chip: LM629, options: BringupOptions, yes: bool) -> int:
    on = (f"axis {axis_name(s, chip.chip_select)} (cs {chip.chip_select}), "
          if s.profile is not None else "")
    click.echo(f"bring-up of {on}{chip.variant.upper()} on {chip.transport.describe()}")

    def report(step: StepResult) -> None:
        color = {True: "green", False: "red", None: "yellow"}[step.ok]
        click.echo(f"  [{click.style(step.verdict, fg=color)}] {step.name:8s} {step.summary}")
        for d in step.details:
            click.echo(f"             {d}")

    def confirm(question: str) -> bool:
        return yes or _abort_is_interrupt(lambda: click.confirm(question, default=False))

    result = run_bringup(chip, options, confirm=confirm, report=report, clock_hz=s.clock_hz,
                         announce=lambda text: log.info("step: %s", text))
    click.echo("verdict: " + ("PASS, every step" if result.passed else "FAIL" if any(
        st.ok is False for st in result.steps) else "INCOMPLETE"))
    # EXIT_CODES (cli/app.py): 5 the chip did not leave reset, 1 a check failed
    return 5 if result.reset_failed else 0 if result.passed else 1


@main.command("list")
def list_cmd() -> None:
    """Ports that can be found: simulators, serial bridges, FT232H adapters."""
    from lm629_host.transports import transport_classes
    for scheme, cls, problem in transport_classes():
        if cls is None:
            click.echo(f"{scheme}://  not available: {problem}")
            continue
        try:
            ports = cls.list_ports()
        except Exception as exc:  # noqa: BLE001 - one backend's failure is one line
            click.echo(f"{scheme}://  listing failed: {exc}")
            continue
        for p in ports:
            mark = "" if p.usable else f"  [cannot open: {p.problem}]"
            click.echo(f"{p.url:27s} {p.description}{mark}")


@main.command()
@click.option("--path", "path_only", is_flag=True, help="Print only the rule file's path.")
def udev(path_only: bool) -> None:
    """The udev rule that lets your user open FT232H adapters (ftdi://) without root: where
    this installation keeps it, and the commands that install it."""
    from lm629_host import data
    if path_only:
        click.echo(str(data.udev_rule()))
        return
    click.echo(f"rule file: {data.udev_rule()}")
    click.echo("install it (once per machine), then replug the adapter:")
    for command in data.udev_install_commands():
        click.echo(f"    {command}")


#: what doctor suggests when a reset or busy check fails
WIRING_HINT = ("  -> a data or control wire may be wrong: run `lm629 wiring --check` (it names the "
               "wire, moving nothing) and compare with `lm629 wiring`")


#: the optional extras (pyproject's ``[project.optional-dependencies]`` less the developers'
#: ``test`` and ``lint``; a test holds the two lists together): extra -> the modules it
#: brings, each with its distribution, and what needs it.  Missing, each is a note, not a
#: problem: a bench without an FT232H needs no pyftdi
OPTIONAL_EXTRAS: dict[str, tuple[tuple[tuple[str, str], ...], str]] = {
    "ftdi": ((("pyftdi", "pyftdi"),), "ftdi://, an FT232H adapter"),
    "plot": ((("matplotlib", "matplotlib"),), "the PNGs of step, tune and scope --png, CSV "
                                              "only without it"),
    "scope": ((("plotext", "plotext"), ("matplotlib", "matplotlib")),
              "lm629 scope's live terminal plot"),
    "vcd": ((("vcd", "pyvcd"),), "--vcd and vcd=, a simulated bus for PulseView and sigrok"),
    "labgrid": ((("labgrid", "labgrid"),), "the labgrid driver, in a venv of its own as it "
                                           "brings a pyserial fork: docs/testing.md"),
}


def _extras() -> tuple[list[tuple[str, bool, str]], set[str]]:
    """(extra, installed, what it says) for each optional extra, and the modules missing."""
    import importlib.util
    from importlib.metadata import PackageNotFoundError, version
    rows, missing = [], set()
    for extra, (modules, needs) in OPTIONAL_EXTRAS.items():
        absent = [m for m, _dist in modules if importlib.util.find_spec(m) is None]
        missing.update(absent)
        if absent:
            rows.append((extra, False, f"not installed ({', '.join(absent)}), optional for "
                                       f"{needs}: pip install 'lm629-host[{extra}]'"))
            continue
        found = []
        for _m, dist in modules:
            try:
                found.append(f"{dist} {version(dist)}")
            except PackageNotFoundError:  # importable from elsewhere (a checkout on the path)
                found.append(dist)
        rows.append((extra, True, f"{', '.join(found)}: {needs}"))
    return rows, missing


@main.command()
def doctor() -> None:
    """What is installed, what can be found and what is wrong (backends, permissions, latency,
    firmware version, round-trip time)."""
    import platform
    import time
    s = _session()
    problems = 0

    def line(name: str, ok: bool, msg: str, optional: bool = False) -> None:
        """``[ok]``, ``[!!]`` (a problem: counted, exit 1), or ``[--]``: an optional part
        not installed, said as such and not counted."""
        nonlocal problems
        problems += not ok
        mark, colour = ("--", "yellow") if optional else ("ok", "green") if ok else ("!!", "red")
        click.echo(f"  [{click.style(mark, fg=colour)}] {name}: {msg}")

    click.echo("python and packages")
    line("python", sys.version_info >= (3, 10), platform.python_version())
    line("lm629-host", True, lm629_host.__version__)
    extras, missing = _extras()
    click.echo("optional extras ([--]: not installed, not a problem)")
    for extra, installed, msg in extras:
        line(extra, True, msg, optional=not installed)
    from lm629_host.transports import transport_classes
    for scheme, cls, problem in transport_classes():
        if cls is None:
            click.echo(f"{scheme}://")
            line(scheme, False, f"transport not available: {problem}")
            continue
        try:
            checks = cls.doctor()
        except Exception as exc:  # noqa: BLE001 - one backend's failure is one line
            click.echo(f"{scheme}://")
            line(scheme, False, f"doctor failed: {exc}")
            continue
        if checks:
            click.echo(f"{scheme}://")
        for c in checks:
            # a transport's note of a module the extras above found missing is that note again
            line(c.name, c.ok, c.message, optional=c.ok and c.name in missing)
    if s.port_given:
        click.echo(f"port {s.port}")
        try:
            chip = s.open(prepare=False)
            line("open", True, chip.transport.describe())
            t0 = time.perf_counter()
            n = 20
            busy = 0
            for _ in range(n):
                st = chip.read_status()
                busy += bool(st & Status.BUSY)
            dt = (time.perf_counter() - t0) / n
            stuck = (f"; the busy bit was set in all {n} reads: the chip is stuck busy (check "
                     "its clock input, its supply and /RST)") if busy == n else ""
            line("status read", busy < n, f"{int(st):02X} ({_flags(st)}), {dt * 1e3:.3f} ms "
                                          f"per round trip (wall clock){stuck}")
            for c in chip.transport.port_checks():
                line(c.name, c.ok, c.message)
                if not c.ok and busy < n:
                    click.echo(WIRING_HINT)
            if busy == n:
                click.echo(WIRING_HINT)
            from lm629_host.cli.common import failsafe_info
            fs, fs_line = failsafe_info(chip.transport)
            line("failsafe", fs is None or (not fs["tripped"] and fs["trip"] is None), fs_line)
        except LM629Error as exc:
            line("open", False, str(exc))
            if isinstance(exc, (BusyTimeout, ResetError)):
                click.echo(WIRING_HINT)
    click.echo("no problems found" if not problems else f"{problems} problem(s) above")
    if problems:
        click.get_current_context().exit(1)


