#!/usr/bin/env python3
"""Tuned gains against the best of a grid search, on motors of different kinds (``sim://``).

For each motor: ``autotune`` (travel 5000, a 2000-count step out and back and a 2000-count
trapezoid move out and back as its test moves) from a fresh chip holding at kp = 20; then every
point of a kp x ki x kd grid on a fresh chip, each measured with the same two test moves
(``tuning.measure_move``, guarded like tuning: a point that would leave the band is stopped and
counted as a fault; the move at the profile the tuner chose for that motor, 0x40000 and 0x2000
where the axis follows them).  The tuned gains are measured again the same way.  "Best" is the
smallest sum of ``tuning.score`` over the two moves (settle time within the tolerance, with
penalties for overshoot and for ending outside it): the same yardstick for both.  Each row
gives the step's figures and the move's (its settle counted from the profile's end).

``--write-docs`` puts the table between the ``bench_tune.py`` markers in docs/cli.md with a
paragraph that says what the rows say (every figure and every claim in it computed from them:
``summary``), and saves the rows in docs/tuning-grid.json, from which the tests render the
block again: a hand edit of it, or a change of the rendering without a new run, fails them.

    python3 tools/bench_tune.py            # the full grid (a few minutes on one core)
    python3 tools/bench_tune.py --write-docs   # ... written into docs/cli.md, with its summary
    python3 tools/bench_tune.py --rows docs/tuning-grid.json   # no run: render saved rows
    python3 tools/bench_tune.py --quick    # a coarse grid
    python3 tools/bench_tune.py --url 'sim+avr://'   # through the compiled bridge firmware
    python3 tools/bench_tune.py --matrix   # the tuner's acceptance: 5 transports x 3 motors

``--matrix``: on each transport the tuner must hold on (``sim://``, ``sim+emu://``, ``sim+avr://``,
``sim+ftdi://``, ``sim+emu://?usb=uno&fast_baud=1000000``) and each of its motors (default,
10x inertia, a holding load of 0.005 N m), ``autotune(chip, travel=2000)`` from a fresh chip
holding at kp = 20, then with the gains it leaves loaded the 2000-count step and the
2000-count trapezoid move at the tuner's profile, each out and back (``measure_move``, band
+/-5000: travel 2000 allows the tuner test moves of 1500 at most), the worse of out and back.
A combination holds when the move ends within 3 counts with an overshoot of at most 20 counts
(1 % of the move); the step's figures are shown beside it.
"""

from __future__ import annotations

import argparse
import datetime
import itertools
import json
import re
import sys
import textwrap
import time
from dataclasses import asdict, dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import lm629_host
from lm629_host.errors import MotionError
from lm629_host.bench.tuning import autotune
from lm629_host.bench.tuning_session import measure_move
from lm629_host.physics.axis import Gains
from lm629_host.physics.metrics import MoveMetrics, score
from lm629_host.physics.predict import MoveProfile

MOTORS = (
    ("default", ""),
    ("10x inertia", "inertia=4e-5"),
    ("holding load", "load_torque=0.004"),
    ("holding load 0.005", "load_torque=0.005"),
    ("low friction", "friction=2e-7&coulomb=2e-5"),
    ("slow amplifier (3 V)", "amp_volts=3"),
)
TRAVEL = 5000
DISTANCE = 2000
TOLERANCE = 2
DURATION = 1.0  #: seconds recorded after each step of the test move (every motor settles)
POLL = 0.002
#: the acceptance's largest overshoot of the trapezoid move (1 % of it; --matrix)
OVERSHOOT_LIMIT = DISTANCE // 100


#: the grid the docs quote (kp x ki x kd; il GRID_IL where ki > 0, ds 1)
FULL_GRID = list(itertools.product((25, 50, 100, 200, 400, 800), (0, 4, 16, 64),
                                   (0, 300, 1000, 3000, 10000, 30000)))
QUICK_GRID = list(itertools.product((25, 100, 400), (0, 16), (0, 1000, 4000, 16000)))
GRID_IL = 4000  #: the integration limit of the grid's points with ki > 0
ROOT = Path(__file__).resolve().parent.parent
CLI_DOC = ROOT / "docs" / "cli.md"
COMMAND = "python3 tools/bench_tune.py --write-docs"
BEGIN, END = "<!-- bench_tune.py: begin -->", "<!-- bench_tune.py: end -->"
#: the rows the docs' block was rendered from (tests/bench/test_tune_docs.py renders them again)
ROWS_FILE = ROOT / "docs" / "tuning-grid.json"


def url_of(base: str, params: str) -> str:
    if not params:
        return base
    return base + ("&" if "?" in base else "?") + params


def fresh(url: str) -> lm629_host.LM629:
    chip = lm629_host.open(url)
    chip.reset()
    chip.load_filter(kp=20)
    chip.update_filter()
    return chip


Measured = tuple[MoveMetrics, MoveMetrics] | None  #: (step, move), None: a fault


@dataclass(frozen=True)
class Side:
    """One set of gains on one motor: where they came from and how the two test moves went."""

    gains: Gains
    measured: Measured
    wall_s: float  #: the tuner's run, or the whole grid's


@dataclass(frozen=True)
class MotorRow:
    """One motor: the tuned gains against the grid's best, both on the tuner's profile."""

    name: str
    params: str
    profile: str  #: the trapezoid move the tuner chose (``MoveProfile``'s words)
    tuned: Side
    best: Side
    faults: int  #: grid points that would have left the band


def measure(url: str, g: Gains, profile: MoveProfile) -> Measured:
    out = []
    for p in (None, profile):
        with fresh(url) as chip:
            try:
                m, _rec = measure_move(chip, g, distance=DISTANCE, travel=TRAVEL,
                                       duration_s=DURATION, tolerance=TOLERANCE, poll_s=POLL,
                                       profile=p)
            except MotionError:
                return None
        out.append(m)
    return out[0], out[1]


def cost(m: Measured) -> float:
    return float("inf") if m is None else sum(score(x, DURATION, TOLERANCE) for x in m)


def run_motor(base: str, name: str, params: str, grid: list[tuple[int, int, int]]) -> MotorRow:
    """Tune one motor, measure the tuned gains, then every grid point; the best by ``cost``."""
    url = url_of(base, params)
    t = time.perf_counter()
    with fresh(url) as chip:
        result = autotune(chip, travel=TRAVEL, distance=DISTANCE, tolerance=TOLERANCE)
    tune_s = time.perf_counter() - t
    assert result.profile is not None
    tuned = measure(url, result.gains, result.profile)
    best: tuple[Gains, Measured] | None = None
    faults = 0
    t = time.perf_counter()
    for kp, ki, kd in grid:
        g = Gains(kp, ki, kd, GRID_IL if ki else 0)
        m = measure(url, g, result.profile)
        faults += m is None
        if best is None or cost(m) < cost(best[1]):
            best = (g, m)
    assert best is not None
    return MotorRow(name, params, str(result.profile), Side(result.gains, tuned, tune_s),
                    Side(best[0], best[1], time.perf_counter() - t), faults)


# ------------------------------------------------------------------------ rows <-> JSON
def rows_to_json(rows: list[MotorRow], grid: list[tuple[int, int, int]], date: str) -> str:
    """The measured rows, the grid and the run's date, for ``--rows`` to render again."""
    return "\n".join(["{", f' "date": {json.dumps(date)},', f' "grid": {json.dumps(grid)},',
                      ' "rows": [', ",\n".join(f"  {json.dumps(asdict(r))}" for r in rows), " ]",
                      "}"])


def _measured(d: list[dict] | None) -> Measured:
    return None if d is None else (MoveMetrics(**d[0]), MoveMetrics(**d[1]))


def _side(d: dict) -> Side:
    return Side(Gains(**d["gains"]), _measured(d["measured"]), d["wall_s"])


def rows_from_json(text: str) -> tuple[list[MotorRow], list[tuple[int, int, int]], str]:
    d = json.loads(text)
    rows = [MotorRow(r["name"], r["params"], r["profile"], _side(r["tuned"]), _side(r["best"]),
                     r["faults"]) for r in d["rows"]]
    return rows, [(kp, ki, kd) for kp, ki, kd in d["grid"]], d["date"]


# ------------------------------------------------------------------------------ rendering
TABLE_HEAD = (
    "| motor | gains from | gains | step: final error | overshoot | settle ms | "
    "peak following error | hunting | move: final error | overshoot | settle ms after the "
    "profile | peak following error | hunting |\n"
    "|---|---|---|---|---|---|---|---|---|---|---|---|---|")


def _span(values: list[int]) -> str:
    lo, hi = min(values), max(values)
    return f"{lo}" if lo == hi else f"{lo}-{hi}"


def describe_grid(grid: list[tuple[int, int, int]]) -> str:
    """``144-point grid (kp 25-800 x ki 0-64 x kd 0-30000, ...)``: from the points."""
    kp, ki, kd = ([p[i] for p in grid] for i in range(3))
    return (f"{len(grid)}-point grid (kp {_span(kp)} x ki {_span(ki)} x kd {_span(kd)}, "
            f"il {GRID_IL} where ki > 0, derivative interval 1)")


def _figures(m: MoveMetrics) -> str:
    settle = "-" if m.settle_s is None else f"{m.settle_s * 1e3:.0f}"
    return (f"{m.final_error:+d} | {m.overshoot} | {settle} | {abs(m.peak_following_error)} | "
            f"{m.hunt}")


def _row(name: str, what: str, side: Side) -> str:
    if side.measured is None:
        return f"| {name} | {what} | {side.gains} | fault | | | | | fault | | | | |"
    step, move = side.measured
    return f"| {name} | {what} | {side.gains} | {_figures(step)} | {_figures(move)} |"


def table_rows(r: MotorRow, points: int) -> list[str]:
    """A motor's two rows: the tuned gains, then the grid's best."""
    return [_row(f"{r.name} (`{r.params or 'defaults'}`, move {r.profile})",
                 f"tune ({r.tuned.wall_s:.1f} s wall)", r.tuned),
            _row("", f"grid best of {points} ({r.best.wall_s:.0f} s wall, {r.faults} left "
                     f"the band)", r.best)]


WORDS = ("no", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten")


def _where(names: list[str], of: int) -> str:
    """``on every motor``, ``on five motors`` (most of them), else the motors by name."""
    if len(names) == of > 1:
        return "on every motor"
    if len(names) > of // 2 and of > 2:
        return f"on {WORDS[len(names)] if len(names) < len(WORDS) else len(names)} motors"
    return f"on {_and(names)}"


def _and(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def _ms(m: MoveMetrics) -> int | None:
    """The settle time as the table shows it (whole ms), so that text and table agree."""
    return None if m.settle_s is None else round(m.settle_s * 1e3)


def _m(side: Side, which: int) -> MoveMetrics:
    """The step's (0) or the move's (1) figures of gains that did not fault."""
    assert side.measured is not None
    return side.measured[which]


def _overshoot(rows: list[MotorRow], which: int) -> str:
    """The tuned gains' overshoot on the step (``which`` 0) or the move (1) against the grid's
    best: the range of each, on which motors the tuned gains overshoot less, and every motor
    where they do not (as much, or more: both figures)."""
    pairs = [(r.name, _m(r.tuned, which).overshoot, _m(r.best, which).overshoot) for r in rows]
    less = [n for n, t, b in pairs if t < b]
    same = [n for n, t, b in pairs if t == b]
    more = [f"{n} ({t} against {b})" for n, t, b in pairs if t > b]
    parts = [f"less {_where(less, len(pairs))}"] if less else []
    if same:
        parts.append(f"as much on {_and(same)}")
    if more:
        parts.append(f"more on {_and(more)}")
    tuned = _span([t for _, t, _ in pairs])
    return (f"{tuned} count{'' if tuned == '1' else 's'} against "
            f"{_span([b for _, _, b in pairs])}: {', '.join(parts)}")


def _settle(rows: list[MotorRow], which: int, what: str) -> str:
    """A sentence (without its full stop): which settles sooner on ``what`` (``which`` 0: the
    step, 1: the move), by how much of the slower time, on which motors; those that never
    settle.  The times as the table shows them (whole ms)."""
    never = [f"{who} on {r.name}" for r in rows for who, side in (("the tuned gains", r.tuned),
             ("the grid's best", r.best)) if _ms(_m(side, which)) is None]
    timed = [(r.name, _ms(_m(r.tuned, which)), _ms(_m(r.best, which))) for r in rows]
    pairs = [(n, t, b) for n, t, b in timed if t is not None and b is not None]
    parts = []
    for label, won in (("the grid's best settles", [(n, (t - b) / t) for n, t, b in pairs if b < t]),
                       ("the tuned gains settle", [(n, (b - t) / b) for n, t, b in pairs if t < b])):
        if won:
            pct = [round(x * 100) for _, x in won]
            parts.append(f"{label} {_span(pct)} % sooner {_where([n for n, _ in won], len(rows))}")
    same = [n for n, t, b in pairs if t == b]
    if same:
        parts.append(f"both as soon on {_and(same)}")
    if never:
        parts.append(f"never within +/-{TOLERANCE} counts in {DURATION:g} s: {_and(never)}")
    return f"On {what} " + "; ".join(parts)  # every motor is in one of the parts


def summary(rows: list[MotorRow]) -> str:
    """The figures of the table in words, every one computed from the rows: where the moves
    ended, overshoot and settle time of the tuned gains against the grid's best, hunting."""
    sides = [(r.name, who, side) for r in rows
             for who, side in (("tuned", r.tuned), ("grid-best", r.best))]
    faults = [f"the {who} gains on {name}" for name, who, side in sides if side.measured is None]
    ends = [(f"the {who} {what} on {name}", m.final_error) for name, who, side in sides
            if side.measured is not None for what, m in zip(("step", "move"), side.measured)]
    out = [f"{what} ({error:+d})" for what, error in ends if abs(error) > TOLERANCE]
    text = []
    if not faults and not out:
        worst = max(abs(error) for _, error in ends)
        edge = [what for what, error in ends if abs(error) == TOLERANCE] if TOLERANCE else []
        text.append(f"Every tuned and grid-best move ended within the tolerance of "
                    f"{TOLERANCE} counts, inside the band" + (
                        f"; at its edge ({TOLERANCE} off): {_and(edge)}." if edge else
                        f" (at most {worst} off)." if worst else " (every one on target)."))
    if out:
        text.append(f"Ended outside the tolerance of {TOLERANCE} counts: {_and(out)}.")
    if faults:
        text.append(f"Left the band (a fault, the motor stopped): {_and(faults)}.")
    both = [r for r in rows if r.tuned.measured is not None and r.best.measured is not None]
    if both:
        text.append(f"The tuned trapezoid moves overshoot "
                    f"{_overshoot(both, 1)}.")
        large = [f"{who} on {r.name} ({_m(side, 1).overshoot})"
                 for r in both for who, side in (("the tuned move", r.tuned),
                                                 ("the grid's best", r.best))
                 if _m(side, 1).overshoot > OVERSHOOT_LIMIT]
        text.append(f"Trapezoid moves that overshoot more than {OVERSHOOT_LIMIT} counts "
                    f"({OVERSHOOT_LIMIT * 100 // DISTANCE} % of the move, the tuner's "
                    f"acceptance): {_and(large)}." if large else
                    f"No trapezoid move overshoots more than {OVERSHOOT_LIMIT} counts "
                    f"({OVERSHOOT_LIMIT * 100 // DISTANCE} % of the move, the tuner's "
                    f"acceptance).")
        text.append(_settle(both, 1, "the move (after the profile)") + ".")
        text.append(_settle(both, 0, "the step") + "; the tuned gains overshoot "
                    f"{_overshoot(both, 0)}.")
    hunters = [(r.name, who, side) for r in rows for who, side in (("tuned gains", r.tuned),
                                                                    ("grid's best", r.best))
               if side.measured is not None and max(m.hunt for m in side.measured)]
    if hunters:
        said = [f"the {who} on {name} ({max(_m(side, i).hunt for i in (0, 1))})"
                for name, who, side in hunters]
        why = ", all with integral action (ki > 0)" if all(
            side.gains.ki for *_, side in hunters) else ""
        text.append(f"Hunting at rest, counts peak to peak over the last "
                    f"{DURATION / 4:g} s: {_and(said)}{why}; none elsewhere.")
    else:
        text.append("Neither the tuned gains nor the grid's best hunt at rest on any motor.")
    return " ".join(text)


def render_docs(rows: list[MotorRow], grid: list[tuple[int, int, int]], date: str) -> str:
    """The block between the markers in docs/cli.md: what was run, the table, its summary."""
    intro = (f"Measured {date} by `{COMMAND}` (this block is its output: run it again to "
             f"refresh; the full grid takes minutes). The tuned gains against the best of a "
             f"{describe_grid(grid)} on the same two test moves ({DISTANCE} counts out and "
             f"back: the step, and the trapezoid at the profile the tuner chose for that "
             f"motor), each from a fresh `sim://` chip; \"best\" is the smallest sum of the two "
             f"moves' scores; `ds` is the derivative interval in samples, settle is to "
             f"+/-{TOLERANCE} counts (the move's from the profile's end), each figure the worse "
             f"of the out and back moves, hunting is peak to peak over the last "
             f"{DURATION / 4:g} s:")
    table = [TABLE_HEAD, *(x for r in rows for x in table_rows(r, len(grid)))]
    return "\n".join([BEGIN, _wrap(intro), "", *table, "", _wrap(summary(rows)), END])


def _wrap(text: str) -> str:
    return textwrap.fill(text, width=95, break_long_words=False, break_on_hyphens=False)


def write_docs(block: str) -> None:
    text = CLI_DOC.read_text()
    if BEGIN not in text or END not in text:
        raise SystemExit(f"{CLI_DOC} has no {BEGIN} ... {END} block: put the two markers "
                         f"where the tuning table goes")
    CLI_DOC.write_text(re.sub(re.escape(BEGIN) + ".*?" + re.escape(END), lambda _: block, text,
                              flags=re.S))


MATRIX_URLS = ("sim://", "sim+emu://", "sim+avr://", "sim+ftdi://",
               "sim+emu://?usb=uno&fast_baud=1000000")
MATRIX_MOTORS = (("default", ""), ("10x inertia", "inertia=4e-5"),
                 ("holding load 0.005 N m", "load_torque=0.005"))
MATRIX_TRAVEL = 2000  #: autotune's travel in the acceptance matrix


def matrix(urls: list[str]) -> int:
    """The acceptance table; the number of combinations that hold."""
    print(f"autotune(chip, travel={MATRIX_TRAVEL}), then {DISTANCE}-count moves out and back "
          f"with the gains loaded (worse of the two); holds: the move within 3 counts, "
          f"overshoot <= {OVERSHOOT_LIMIT}")
    print("| transport | motor | gains | step: final error | overshoot | move: final error | "
          "overshoot | peak following error | holds | wall s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    held = 0
    for base in urls:
        for name, params in MATRIX_MOTORS:
            t = time.perf_counter()
            with fresh(url_of(base, params)) as chip:
                try:
                    r = autotune(chip, travel=MATRIX_TRAVEL)
                    assert r.profile is not None
                    step, _ = measure_move(chip, None, distance=DISTANCE, travel=TRAVEL,
                                           duration_s=DURATION, tolerance=TOLERANCE)
                    move, _ = measure_move(chip, None, distance=DISTANCE, travel=TRAVEL,
                                           duration_s=DURATION, tolerance=TOLERANCE,
                                           profile=r.profile)
                except MotionError as exc:
                    print(f"| {base} | {name} | fault: {str(exc)[:120]} | | | | | | no | "
                          f"{time.perf_counter() - t:.0f} |")
                    sys.stdout.flush()
                    continue
            ok = abs(move.final_error) <= 3 and move.overshoot <= OVERSHOOT_LIMIT
            held += ok
            print(f"| {base} | {name} | {r.gains} | {step.final_error:+d} | {step.overshoot} | "
                  f"{move.final_error:+d} | {move.overshoot} | {abs(move.peak_following_error)} "
                  f"| {'yes' if ok else 'NO'} | {time.perf_counter() - t:.0f} |")
            sys.stdout.flush()
    print(f"{held} of {len(urls) * len(MATRIX_MOTORS)} hold")
    return held


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--url", default="sim://", help="base URL (motor parameters are appended)")
    ap.add_argument("--quick", action="store_true", help="a coarse grid")
    ap.add_argument("--motor", action="append", help="only these motors (names as listed)")
    ap.add_argument("--matrix", action="store_true",
                    help="the acceptance matrix: autotune(travel=2000) on 5 transports x 3 "
                         "motors, then 2000-count moves (--url: only that transport)")
    ap.add_argument("--write-docs", action="store_true",
                    help=f"write the table and its summary into {CLI_DOC.relative_to(ROOT)} "
                         f"(the full grid, every motor, sim://)")
    ap.add_argument("--rows", metavar="FILE",
                    help=f"no run: render the rows a run saved (--write-docs saves them in "
                         f"{ROWS_FILE.relative_to(ROOT)})")
    args = ap.parse_args()
    if args.matrix:
        matrix([args.url] if args.url != "sim://" or "--url" in sys.argv else list(MATRIX_URLS))
        return
    if args.write_docs and (args.quick or args.motor or args.url != "sim://"):
        ap.error("--write-docs writes what the docs describe: the full grid on every motor "
                 "on sim:// (no --quick, --motor or --url)")
    if args.rows:
        rows, grid, date = rows_from_json(Path(args.rows).read_text())
    else:
        date = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        grid = QUICK_GRID if args.quick else FULL_GRID
        print(f"the {describe_grid(grid)}; test moves {DISTANCE:+d} counts out and back "
              f"(a step, and a trapezoid at the tuner's profile), tolerance {TOLERANCE}, "
              f"{DURATION:g} s per move after its profile")
        print(TABLE_HEAD)
        rows = []
        for name, params in MOTORS:
            if args.motor and name not in args.motor:
                continue
            rows.append(run_motor(args.url, name, params, grid))
            print("\n".join(table_rows(rows[-1], len(grid))))
            sys.stdout.flush()
    block = render_docs(rows, grid, date)
    print(block)
    if args.write_docs:
        ROWS_FILE.write_text(rows_to_json(rows, grid, date) + "\n")
        write_docs(block)
        print(f"{CLI_DOC}: the tuning table written (its rows: {ROWS_FILE})", file=sys.stderr)


if __name__ == "__main__":
    main()
