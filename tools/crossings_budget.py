"""Does the crossings machine's CI budget still find the product bugs it has found?

Each bug the machine found is put back by hand (the smallest edit that brings the old
behaviour back: the table BUGS below), in a copy of this checkout, and the machine runs CI's
own derandomized sequences of one link at a budget, stopped at its first failure:

    python3 tools/crossings_budget.py                       # CI's budgets, every bug
    python3 tools/crossings_budget.py --link sim:// --budget 40x30 --budget 50x30
    python3 tools/crossings_budget.py --bug d358efb -j 2

One row per link, budget and bug: the sequence that found it (``F@n``: the bug's failure,
its first line; ``H@n``: a hang, sequence n did not end within ``--stall`` seconds) or
``MISSED`` (``missed`` on a link where CI need not find it), and the clean code's run
(passed, its sequences and steps, seconds).  The tool exits 1 when a bug is missed on a link
its ``found_on`` names, or when the clean code fails.

Why a tool: a budget is a set of sequences, not a prefix of a bigger one (a smaller
``max_examples`` changes hypothesis's first phase, other steps change the draws), so "the
smallest budget that still finds them" is measured, never inferred; and it must be measured
again whenever the machine's rules, hypothesis (pinned in pyproject.toml) or the code a bug's
edit touches change (docs/testing.md, "The crossings machine's budget").  A failing run is
stopped at its first failure (no shrinking), so a bug found costs seconds.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MACHINE = "tests/crossings/test_api_state_machine.py"
#: what the copies leave out: history, environments, caches
SKIP = shutil.ignore_patterns(".git", ".venv*", ".hypothesis", "__pycache__", ".pytest_cache",
                              ".mypy_cache", ".ruff_cache")
LINKS = ("sim://", "sim+emu://", "sim+avr://")


@dataclass(frozen=True)
class Edit:
    path: str
    old: str
    new: str


@dataclass(frozen=True)
class Bug:
    commit: str  #: the fix
    what: str
    edits: tuple[Edit, ...]
    #: the links where CI's budget finds it (the others may, and are not required to)
    found_on: tuple[str, ...]
    #: the fix's own regression test, which fails with the bug back (--verify)
    test: str


BUGS = (
    Bug("9e54169", "a velocity run crossing the wrap before its first read is 2^31 off",
        (Edit("lm629_host/chip/lm629.py",
              'if start and velocity_mode and not self.positions.knows("desired"):',
              'if False and start and velocity_mode and not self.positions.knows("desired"):'),),
        ("sim://", "sim+emu://", "sim+avr://"),
        "tests/chip/test_crossings.py::test_a_velocity_run_whose_first_read_is_past_the_wrap"),
    Bug("9c21553", "the selftest refuses its own velocity runs on an axis with soft limits",
        (Edit("lm629_host/bench/selftest/runner.py",
              "limits, chip.limits = chip.limits, None", "limits = chip.limits"),),
        ("sim://",),
        "tests/bench/test_selftest.py::test_an_axis_with_soft_limits_passes_and_keeps_them"),
    Bug("bc691df", "the selftest hangs when the chip's positions are not the model's",
        # the later guard (f280acd, positions_fault) is lifted too: alone, the first edit
        # changes nothing on today's code
        (Edit("lm629_host/bench/selftest/lockstep.py",
              "most = (self.chip.clock.now() - self._stt_time) / period * CHIP_RATE_MAX",
              "most = float(1 << 62)"),
         Edit("lm629_host/bench/selftest/checks.py",
              "fault = positions_fault(ls)", "fault = None")),
        ("sim://", "sim+emu://", "sim+avr://"),
        "tests/bench/test_selftest.py::test_a_chip_whose_positions_are_not_the_models_is_told_as_such"),
    Bug("ffe8f73", "the Python far end runs a whole WAIT_STATUS past a host byte",
        (Edit("lm629_host/sim/bridge/runner.py",
              "if self.host_byte_waiting or heard is not None and heard(t) is not None:",
              "if heard is not None and heard(t) is not None:"),),
        ("sim+emu://",),
        "tests/sim/test_far_ends.py::test_a_host_byte_ends_a_wait_on_the_python_far_end_in_process"),
    Bug("d358efb", "the selftest of a shaft parked on its index differs with where SIP lands",
        (Edit("lm629_host/bench/selftest/checks.py",
              '("t", latch_wait_us(ls.model.clock_hz)), ("s",),', '("s",),'),),
        ("sim://",),
        "tests/chip/test_crossings.py::"
        "test_a_selftest_of_a_shaft_parked_on_its_index_passes_wherever_in_the_count_it_rests"),
)


def ci_budgets() -> dict[str, str]:
    """CI's budget per link, read from the machine's LINKS (one home for it)."""
    text = (ROOT / MACHINE).read_text()
    pairs = re.findall(r'\("(sim[^"?]*://)[^"]*", Budget\((\d+), (\d+)\)\)', text)
    found = {url: f"{examples}x{steps}" for url, examples, steps in pairs}
    missing = [link for link in LINKS if link not in found]
    if missing:
        raise SystemExit(f"{MACHINE}: no CI budget found for {', '.join(missing)} in LINKS")
    return found


def copy_with(bug: Bug | None, into: Path) -> Path:
    """This checkout (built images and modules included) with ``bug`` put back."""
    dest = into / (bug.commit if bug else "clean")
    shutil.copytree(ROOT, dest, ignore=SKIP, symlinks=True)
    if bug is None:
        return dest
    for edit in bug.edits:
        path = dest / edit.path
        text = path.read_text()
        if text.count(edit.old) != 1:
            raise SystemExit(f"{bug.commit}: {edit.path} no longer holds {edit.old!r} once "
                             "(the code moved): update the edit in tools/crossings_budget.py's "
                             "BUGS so that it puts the bug back again")
        path.write_text(text.replace(edit.old, edit.new))
    return dest


def _env(tree: Path) -> dict[str, str]:
    env = dict(os.environ, PYTHONPATH=str(tree))
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def run(tree: Path, link: str, budget: str, stall: float) -> tuple[str, float, bool]:
    """The machine on ``link`` at ``budget`` in ``tree``: (result, seconds, passed)."""
    env = _env(tree) | {"LM629_CROSSINGS": "prove", "LM629_CROSSINGS_BUDGET": budget,
                        "LM629_CROSSINGS_STALL": str(stall)}
    t0 = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-s", "-n", "0", "-p", "no:cacheprovider",
         f"{MACHINE}::test_the_api_agrees_with_the_simulator[{link}]"],
        cwd=tree, env=env, capture_output=True, text=True)
    seconds = time.monotonic() - t0
    out = done.stdout + done.stderr
    started = re.findall(r"\[crossings\] sequence (\d+)", out)
    last = started[-1] if started else "?"
    if re.search(r"^Timeout \(", out, re.M):
        return f"H@{last}", seconds, False
    if done.returncode == 0:
        if re.search(r"\b1 skipped\b", out):
            return "skipped: " + (re.findall(r"SKIPPED.*?: (.*)", out) or ["?"])[0], seconds, True
        figures = re.search(r"crossings \(prove\): \S+ (\d+) examples, (\d+) steps", out)
        what = f"{figures[1]} sequences, {figures[2]} steps" if figures else "passed"
        return f"passed ({what})", seconds, True
    first = re.search(r"^E +(.+)$", out, re.M)
    return f"F@{last}: {first[1][:80] if first else out.strip().splitlines()[-1][:80]}", \
        seconds, False


def verify(tree: Path, bug: Bug) -> str:
    """The bug's own regression test on the copy: it must fail (or hang) with the bug back."""
    try:
        done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", "0", "-x",
                               "-p", "no:cacheprovider", bug.test], cwd=tree, env=_env(tree),
                              capture_output=True, text=True, timeout=60)
    except subprocess.TimeoutExpired:
        return "its test hangs (the bug is back)"
    if done.returncode == 0:
        raise SystemExit(f"{bug.commit}: its test {bug.test} passes with the edit: the edit "
                         "no longer puts the bug back; update tools/crossings_budget.py's BUGS")
    return "its test fails (the bug is back)"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--link", action="append", choices=LINKS,
                    help="a link (repeatable; default: all three)")
    ap.add_argument("--budget", action="append", metavar="EXAMPLESxSTEPS",
                    help="a budget to try (repeatable; default: CI's, per link)")
    ap.add_argument("--bug", action="append", choices=[b.commit for b in BUGS],
                    help="one bug (repeatable; default: every one)")
    ap.add_argument("--stall", type=float, default=25.0,
                    help="seconds a sequence may run before it counts as a hang (sim+avr:// "
                         "gets 2.4x: the firmware in simavr)")
    ap.add_argument("--verify", action="store_true",
                    help="first run each bug's own regression test: it must fail")
    ap.add_argument("-j", type=int, default=1, help="runs at a time (each takes one core)")
    args = ap.parse_args(argv)
    for b in args.budget or ():
        if not re.fullmatch(r"[1-9]\d*x[1-9]\d*", b):
            ap.error(f"--budget {b!r}: EXAMPLESxSTEPS, for example 50x30")
    links = args.link or list(LINKS)
    ci = ci_budgets()
    bugs = [b for b in BUGS if not args.bug or b.commit in args.bug]

    with tempfile.TemporaryDirectory(prefix="crossings-budget-") as tmp:
        trees = {None: copy_with(None, Path(tmp))} | {b.commit: copy_with(b, Path(tmp))
                                                       for b in bugs}
        if args.verify:
            for b in bugs:
                print(f"{b.commit}: {verify(trees[b.commit], b)}", flush=True)
        jobs = [(link, budget, bug) for link in links for budget in (args.budget or [ci[link]])
                for bug in [None, *bugs]]

        def one(job):
            link, budget, bug = job
            stall = args.stall * (2.4 if link == "sim+avr://" else 1)
            return job, run(trees[bug.commit if bug else None], link, budget, stall)

        bad = 0
        print(f"{'link':<11} {'budget':<7} {'bug':<8} result")
        with ThreadPoolExecutor(max(1, args.j)) as pool:
            for (link, budget, bug), (result, seconds, passed) in pool.map(one, jobs):
                name = bug.commit if bug else "clean"
                if bug is None:
                    bad += not passed
                elif passed and not result.startswith("skipped"):
                    required = link in bug.found_on
                    result = "MISSED" if required else "missed (CI need not find it here)"
                    bad += required
                print(f"{link:<11} {budget:<7} {name:<8} {result}  ({seconds:.1f} s)",
                      flush=True)
    if bad:
        print(f"{bad} row(s) fail: a bug missed where CI must find it, or the clean code "
              "failing", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
