"""Commands that read and set up the chip: ``status``, ``reset``, ``filter``, ``index``,
``breakpoint``, ``limit``, ``watch`` and ``raw``."""

from __future__ import annotations

import contextlib
from typing import Any

import click

from lm629_host.errors import ArgumentError, CommandError
from lm629_host.errors import check_int
from lm629_host.bus.opcodes import FIXED_ONE, VELOCITY_MAX, Status
from lm629_host.chip.supervise import search_index
from lm629_host.cli.app import _session, axis_name, main
from lm629_host.cli.common import (
    _flags,
    _position,
    _show_position,
    _wait_flag,
    check_filter_options,
    failsafe_info,
    snapshot_dict,
)
from lm629_host.cli.types import FINITE, INT, SIGNED_ARGS, check_writable, positive


@main.command()
@click.option("--json", "as_json", is_flag=True, help="One JSON object on stdout.")
def status(as_json: bool) -> None:
    """Status byte and signals register decoded, positions, velocities, integration sum."""
    s = _session()
    from lm629_host.cli import axes
    if axes.several(s):
        return axes.status(s, as_json, snapshot_dict)
    chip = s.open()
    snap = chip.snapshot()
    d = snapshot_dict(snap, s.scale)
    name = axes.axis_name(s, chip.chip_select) if s.profile is not None else None
    fs, fs_line = failsafe_info(chip.transport)
    d["failsafe"] = fs
    rate = getattr(chip.transport, "line_rate", None)  # a serial bridge's line: rate and why
    if rate is not None:
        d["link"] = dict(zip(("baud", "why"), rate()))
    if as_json:
        import json  # here: a status is text unless asked (json costs every start ~1 ms)
        click.echo(json.dumps(d if name is None else {"axis": chip.chip_select, "name": name, **d},
                              indent=2))
        return
    if name is not None:  # the profile names it: say which axis this is
        click.echo(f"axis     {name} (cs {chip.chip_select})")
    click.echo(f"status   {d['status']}  {' '.join(d['status_flags']) or '-'}")
    click.echo(f"signals  {d['signals']}  {' '.join(d['signals_flags']) or '-'}")
    click.echo(f"position desired {snap.desired_position}  actual {snap.real_position}  "
               f"error {snap.following_error:+d} counts")
    click.echo(f"velocity desired {snap.desired_velocity / FIXED_ONE:.5f}  actual "
               f"{snap.real_velocity} counts/sample")
    if s.scale is not None:
        click.echo(f"         actual {d['real_position_rev']:.4f} rev, "
                   f"{d['real_velocity_rpm']:.1f} rpm (desired {d['desired_velocity_rpm']:.1f})")
    click.echo(f"integration sum {snap.integration_sum}")
    click.echo(f"failsafe {fs_line}")
    if "link" in d:
        click.echo(f"link     {d['link']['baud']} baud, {d['link']['why']}")


@main.command()
def clear() -> None:
    """Acknowledge the bridge's failsafe trip (after a host fell silent mid-move, the bridge
    stopped every chip and refuses trajectory commands until a host acknowledges); say what
    it was, and arm the failsafe again."""
    chip = _session().open(prepare=False)
    t = chip.transport
    if t.failsafe_state() is None:
        click.echo("this port has no far-side failsafe: nothing to acknowledge")
        return
    trip = chip.clear_failsafe()
    click.echo(f"acknowledged: {trip.describe()}" if trip is not None
               else "no failsafe trip latched")


@main.command()
def reset() -> None:
    """Reset the chip and check it came back (AN-706 4.4.1)."""
    chip = _session().open(prepare=False)
    st, seen = chip.reset_statuses()
    click.echo(f"reset ok: status bytes {' '.join(f'{x:02X}' for x in seen)}, now {int(st):02X}")


@main.command("filter")
@click.option("--kp", type=INT, help="Proportional gain, 0..32767.")
@click.option("--ki", type=INT, help="Integral gain, 0..32767.")
@click.option("--kd", type=INT, help="Derivative gain, 0..32767.")
@click.option("--il", type=INT, help="Integration limit, 0..32767.")
@click.option("--ds", type=int, help="Derivative sampling interval, 1..256 samples.")
@click.option("--no-update", is_flag=True, help="Load only (LFIL), no UDF.")
def filter_cmd(kp: int | None, ki: int | None, kd: int | None, il: int | None, ds: int | None,
               no_update: bool) -> None:
    """Load PID coefficients (LFIL) and apply them (UDF)."""
    if all(v is None for v in (kp, ki, kd, il, ds)):
        raise click.UsageError("give at least one of --kp --ki --kd --il --ds")
    s = _session()
    chip = s.open()
    check_filter_options(chip, kp, ki, kd, il, ds)  # before any traffic
    if ds is None and not s.is_sim:
        # the chip cannot report its derivative interval and every LFIL carries it (AN-706
        # 4.5.1): a new process does not know the last one, so say what is sent
        click.echo("lm629: no --ds: the derivative interval is set to 1 sample (pass --ds N "
                   "to keep another one)", err=True)
    chip.load_filter(kp, ki, kd, il, ds)
    if not no_update:
        chip.update_filter()
    loaded = ", ".join(f"{k}={v}" for k, v in dict(kp=kp, ki=ki, kd=kd, il=il, ds=ds).items()
                       if v is not None)
    on = f" on axis {axis_name(s, chip.chip_select)}" if s.profile is not None else ""
    click.echo(f"filter loaded{'' if no_update else ' and updated'}{on}: {loaded}")


@main.command()
@click.option("--wait", "wait_s", type=FINITE, default=None,
              help="Wait up to this many seconds for the index pulse and print where it was.")
@click.option("--search", type=INT, default=None, is_flag=False, flag_value="0", metavar="[WORD]",
              help="Turn slowly (velocity mode, raw word) until the index is seen, then stop; "
                   "on an axis with soft limits a move towards max (min: a negative "
                   "index_velocity), ending there at the latest; no WORD: the profile's "
                   "index_velocity.")
def index(wait_s: float | None, search: int | None) -> None:
    """Latch the position at the next index pulse (SIP).  Without --search nothing moves, and
    a wait that times out leaves the motor as it was."""
    positive("--wait", wait_s)
    if search is not None and search != 0 and not 1 <= search <= VELOCITY_MAX:
        raise click.BadParameter(f"{search} must be a velocity word 1..{VELOCITY_MAX}",
                                 param_hint="--search")
    s = _session()
    from lm629_host.cli import profile
    search, forward = profile.index_search(s, search)
    chip = s.open()
    if search is not None:  # the library's search: armed, turned, stopped, at rest; on an
        # axis with soft limits a move towards the limit that ends there at the latest
        at = search_index(chip, search, timeout=wait_s or 10.0, forward=forward)
        click.echo(f"index at position {_show_position(s, at)}")
        return
    chip.reset_interrupts(Status.INDEX_PULSE)
    chip.set_index_position()
    if wait_s is None:
        click.echo("index armed (SIP): read it later with `lm629 status` / RDIP")
        return
    # only waiting: a timeout must not touch a servo holding position
    _wait_flag(chip, Status.INDEX_PULSE, "the index pulse (status bit 3)", wait_s)
    click.echo(f"index at position {_show_position(s, chip.read_index_position())}")


@main.command(context_settings=SIGNED_ARGS)
@click.argument("position", type=FINITE)
@click.option("--relative", "-r", is_flag=True, help="Relative to the current target (SBPR).")
@click.option("--raw", is_flag=True, help="Counts even with --lines.")
@click.option("--wait", "wait_s", type=FINITE, default=None, help="Wait for it (seconds).")
def breakpoint(position: float, relative: bool, raw: bool, wait_s: float | None) -> None:  # noqa: A001 - the command is `lm629 breakpoint`
    """Set a breakpoint (SBPA/SBPR) at POSITION (counts; revolutions with --lines); status
    bit 6 when the position passes it."""
    s = _session()
    counts = _position(s, position, "POSITION", raw)
    positive("--wait", wait_s)
    chip = s.open()
    chip.set_breakpoint(counts, relative=relative)
    chip.reset_interrupts(Status.BREAKPOINT)
    click.echo(f"breakpoint {'relative ' if relative else ''}{_show_position(s, counts)} set")
    if wait_s is not None:
        _wait_flag(chip, Status.BREAKPOINT, "the breakpoint (status bit 6)", wait_s)
        click.echo(f"breakpoint reached at {_show_position(s, chip.read_real_position())}")


@main.command(context_settings=SIGNED_ARGS)
@click.argument("threshold", type=INT)
@click.option("--stop", "stop_motor", is_flag=True,
              help="Also turn the motor off when exceeded (LPES); default flag only (LPEI).")
def limit(threshold: int, stop_motor: bool) -> None:
    """Following-error limit in counts (LPEI, or LPES with --stop)."""
    try:
        check_int("THRESHOLD", threshold, 0, 0x7FFF)
    except ArgumentError:  # the argument the user typed, in its own words
        raise click.BadParameter(f"{threshold} counts is outside 0..32767",
                                 param_hint="THRESHOLD") from None
    chip = _session().open()
    chip.load_position_error(threshold, stop=stop_motor)
    click.echo(f"{'LPES' if stop_motor else 'LPEI'} {threshold} counts: status bit 5"
               + (" and motor off" if stop_motor else "") + " when the error exceeds it")


@main.command()
@click.option("--rate", type=FINITE, default=10.0, show_default=True, help="Rows per second.")
@click.option("--count", type=int, default=None, help="Stop after this many readings (a row per axis each).")
@click.option("--csv", "csv_path", type=click.Path(dir_okay=False), default=None,
              help="Also log every row to this CSV file.")
def watch(rate: float, count: int | None, csv_path: str | None) -> None:
    """A live table of desired/actual position, velocity, error and flags (Ctrl-C ends it).

    The rows are timed on the chip's clock (simulated time on sim://), t_s from the first
    row: the transport's clock counts from whenever it started (a served bench, a bridge's
    timer), which says nothing to the user."""
    import csv as csvmod
    if not 0 < rate <= 1000:
        raise click.BadParameter(f"{rate:g} must be in 0..1000 rows per second",
                                 param_hint="--rate")
    if count is not None and count < 1:
        raise click.BadParameter(f"{count} must be at least 1", param_hint="--count")
    if csv_path:
        check_writable(csv_path, "--csv")
    s = _session()
    scale = s.scale
    from lm629_host.cli import axes
    if axes.several(s):
        return axes.watch_rows(s, count, rate, _flags, csv_path)
    chip = s.open()
    f = open(csv_path, "w", newline="") if csv_path else None  # noqa: SIM115 - closed in finally
    writer = csvmod.writer(f) if f else None
    header: tuple[str, ...] = ("t_s", "desired_position", "real_position", "following_error",
              "desired_velocity", "real_velocity", "status", "flags")
    if scale is not None:
        header = header[:6] + ("real_position_rev", "real_velocity_rpm") + header[6:]
    if writer:
        writer.writerow(header)
    click.echo(f"{'t_s':>9} {'desired':>10} {'actual':>10} {'error':>7} {'dv':>10} {'rv':>6} "
               + (f"{'rev':>10} {'rpm':>8} " if scale is not None else "") + f"{'st':>3} flags")
    n = 0
    start = chip.clock.now()
    # rows timed on the far side where the transport records there (lm629_host.chip.recording:
    # the bridge's timer, the simulator's clock); else polled from the host
    from lm629_host.chip.recording import far_snapshots
    recorded = far_snapshots(chip, 1.0 / rate, count or 0)
    t0: float | None = None
    try:
        while count is None or n < count:
            snap = chip.snapshot() if recorded is None else next(recorded)
            if t0 is None:
                t0 = snap.time
            row: tuple[Any, ...] = (
                f"{snap.time - t0:.4f}", snap.desired_position, snap.real_position,
                snap.following_error, f"{snap.desired_velocity / FIXED_ONE:.4f}",
                snap.real_velocity)
            units = ""
            if scale is not None:
                extra = (f"{scale.revolutions(snap.real_position):.4f}",
                         f"{scale.rpm(snap.real_velocity * FIXED_ONE):.1f}")
                row += extra
                units = f"{extra[0]:>10} {extra[1]:>8} "
            row += (f"{int(snap.status):02X}", _flags(snap.status))
            click.echo(f"{row[0]:>9} {row[1]:>10} {row[2]:>10} {row[3]:>+7} {row[4]:>10} "
                       f"{row[5]:>+6} {units}{row[-2]:>3} {row[-1]}")
            if writer:
                writer.writerow(row)
            n += 1
            if recorded is None and (count is None or n < count):  # a fixed cadence: no drift
                chip.clock.sleep(max(0.0, start + n / rate - chip.clock.now()))
    except KeyboardInterrupt:
        # watching moves nothing, so nothing is stopped; the exit code says how it ended
        with contextlib.suppress(OSError, ValueError):
            click.echo(f"({n} rows)", err=True)
        raise
    finally:
        if recorded is not None:
            recorded.close()  # stops the far side's recording
        if f:
            f.close()


@main.command()
@click.argument("command", type=INT)
@click.argument("words", type=INT, nargs=-1)
@click.option("--read", "read_n", type=int, default=0, help="Words to read after the command.")
def raw(command: int, words: tuple[int, ...], read_n: int) -> None:
    """Send a COMMAND byte (0x1F, 1Fh) with WORDS to write, or --read N words: for experts.
    Exit 6 when the chip sets its command-error bit in answer."""
    check_int("command", command, 0, 0xFF, hex_digits=2)
    for w in words:
        check_int("word", w, 0, 0xFFFF, hex_digits=4)
    check_int("--read", read_n, 0, 16)
    if words and read_n:
        raise click.BadParameter("a command either writes words or reads them, not both",
                                 param_hint="--read")
    chip = _session().open()
    chip.reset_interrupts(Status.COMMAND_ERROR)  # so that the flag after it is its own
    got = chip.raw(command, words, read_n)
    st = chip.sync()
    out = " ".join(f"{w:04X}" for w in got)
    click.echo((f"read {out}  " if got else "") + f"status {int(st):02X} ({_flags(st)})")
    if st & Status.COMMAND_ERROR:
        raise CommandError(f"command {command:02X}h", int(st))


