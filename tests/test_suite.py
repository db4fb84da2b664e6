"""The suite's own shape (docs/testing.md, "The project's own suite"): which tests run beside
the CPU hogs, which stay on one worker, what the quick loop leaves out, what a plain
``pytest`` says.  The real suite's marks are read from one collection in a child process."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from selection import auto_workers, what_runs
from warm import MIN_STALE, rewritten_copy, stale, start_collection
from xdist_groups import shared_fixture_group

ROOT = Path(__file__).resolve().parents[1]

_DUMP = """
import json, sys, pytest
class Dump:
    def pytest_collection_finish(self, session):
        out = [{"id": i.nodeid, "marks": sorted({m.name for m in i.iter_markers()}),
                "group": [m.args[0] for m in i.iter_markers("xdist_group")]} for i in session.items]
        json.dump(out, open(sys.argv[1], "w"))
sys.exit(pytest.main(["--collect-only", "-q", "-n", "0", "-p", "no:cacheprovider",
                      *sys.argv[2:]], plugins=[Dump()]))
"""


@pytest.fixture(scope="module")
def suite(tmp_path_factory) -> list[dict]:
    """Every test of the suite with its marks and xdist group, as CI's run collects them."""
    out = tmp_path_factory.mktemp("suite") / "items.json"
    p = subprocess.run([sys.executable, "-c", _DUMP, str(out)], cwd=ROOT, capture_output=True,
                       text=True, timeout=300)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    return json.loads(out.read_text())


def _ci_pytest_lines() -> list[str]:
    run = re.sub(r"\\\n\s*", "", (ROOT / ".ci" / "run").read_text())
    return re.findall(r"python3 -m pytest [^&\n]*", run)


def test_ci_runs_every_test_once_and_only_the_under_load_ones_beside_the_hogs(suite):
    """One run, every test once; the hogs burn beside the tests that assert timing under load
    (a failsafe trip, a late host), not beside every served bench: a journey or a docs page
    beside two hogs proves nothing more and runs three times slower."""
    (line,) = _ci_pytest_lines()
    assert " -m " not in line.removeprefix("python3 -m pytest") and "--cpu-hogs 2" in line
    under = [t for t in suite if "under_load" in t["marks"]]
    served = [t for t in suite if "served" in t["marks"]]
    assert any("test_served_bench_trip" in t["id"] for t in under)
    assert any("test_late_host" in t["id"] for t in under)
    assert len(under) < len(served) / 2, f"{len(under)} of {len(served)} served tests under load"
    assert not [t["id"] for t in under if "test_journey" in t["id"] or "test_docs" in t["id"]]


def test_the_hogs_burn_only_while_an_under_load_test_runs(pytester, monkeypatch):
    """Two workers, the hogs shared (tests/hogs.py): burning while either worker runs an
    under_load test, stopped again once none does; the other tests run without them."""
    monkeypatch.setenv("PYTHONPATH", str(Path(__file__).parent))
    pytester.makeconftest("""
        import hogs, pytest
        pytest_plugins = []
        _H = []
        def pytest_sessionstart(session):
            if not hasattr(session.config, "workerinput"):
                _H.append(hogs.Hogs(2))
        def pytest_sessionfinish(session):
            while _H:
                _H.pop().close()
        @pytest.fixture(autouse=True)
        def _beside(request):
            if request.node.get_closest_marker("under_load") is None:
                yield
                return
            with hogs.beside():
                yield
    """)
    pytester.makepyfile(test_h="""
        import time, hogs, pytest

        @pytest.mark.parametrize("k", range(2))
        @pytest.mark.under_load
        def test_loaded(k):
            time.sleep(0.05)  # the hogs' state settles after SIGCONT
            assert hogs.running() == [True, True] and hogs.count() >= 1

        def test_plain():
            time.sleep(1.0)  # after both loaded tests
            assert hogs.running() == [False, False] and hogs.count() == 0
    """)
    r = pytester.runpytest_subprocess("-p", "no:randomly", "-n", "2", "--dist", "load",
                                      "-o", "addopts=", "-m", "under_load or not under_load")
    r.assert_outcomes(passed=3)


def test_both_workers_share_the_long_tests(suite):
    """One test at a time (-n auto, pyproject's --dist loadgroup; no file kept whole): the crossings machine's links
    run as separate tests, free to go to separate workers; a group only where tests share a
    fixture wider than a test, and a docs page's blocks together, in order."""
    addopts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"][
        "ini_options"]["addopts"]
    assert "--dist loadgroup" in addopts
    assert all(" -n auto " in line and "--dist" not in line for line in _ci_pytest_lines())
    links = [t for t in suite if "test_api_state_machine.py::test_the_api_agrees" in t["id"]]
    assert len(links) == 3 and not [t for t in links if t["group"]]
    docs = {}
    for t in suite:
        if "test_doc_block[" in t["id"]:
            page = t["id"].split("[", 1)[1].split(":", 1)[0]
            docs.setdefault(t["group"][0], set()).add(page)
    assert len(docs) > 5 and all(len(pages) == 1 for pages in docs.values()), docs
    journey = {t["group"][0] for t in suite if "test_journey.py::" in t["id"]}
    assert len(journey) == 2  # the python bench and the firmware bench, each on one worker


def test_the_quick_loop_starts_no_bench_and_no_firmware(suite):
    quick = [t["id"] for t in suite if "slow" not in t["marks"]]
    assert len(quick) > len(suite) / 2
    for t in suite:
        if t["id"] in quick:
            assert not {"served", "under_load", "long"} & set(t["marks"]), t["id"]
            assert "sim+avr" not in t["id"] and "test_api_state_machine" not in t["id"], t["id"]
    assert not [i for i in quick if "test_first_sim_avr_use_says_what_it_builds" in i]


def test_a_module_fixture_keeps_its_tests_together_per_parameter(pytester):
    items = pytester.getitems("""
        import pytest

        @pytest.fixture(scope="module", params=["python", "firmware"])
        def bench(request):
            return request.param

        @pytest.fixture
        def own():
            return 1

        def test_a(bench): pass
        def test_b(bench, own): pass
        def test_c(own): pass

        @pytest.mark.xdist_group("mine")
        def test_d(bench): pass
    """)
    groups = {i.name: shared_fixture_group(i, pytester.path) for i in items}
    assert groups["test_a[python]"] == groups["test_b[python]"] != groups["test_a[firmware]"]
    assert groups["test_a[python]"].endswith("bench=python")
    assert groups["test_c"] is None  # a test of its own goes wherever a worker is free
    assert groups["test_d[python]"] is None  # its own mark wins


def test_a_plain_pytest_says_what_it_runs():
    line = what_runs("", False, 0)
    assert line.startswith("lm629-host: every test in one process (-n auto") and "--long" in line
    assert "-m 'not slow'" in line and ".ci/run" in line
    assert "on 2 workers" in what_runs("", False, 0, 2)
    assert "beside 2 CPU hogs" in what_runs("under_load", False, 2)
    assert "-m 'under_load'" in what_runs("under_load", False, 2)


def test_n_auto_starts_three_workers_a_core_and_two_for_the_quick_loop():
    """-n auto: the whole suite waits in real time half of its time, the quick loop never."""
    assert auto_workers("", 2) == 6 and auto_workers("", 1) == 3
    assert auto_workers("served", 2) == 6 and auto_workers("under_load", 2) == 6
    assert auto_workers("not slow", 2) == 4
    assert auto_workers("not  slow and not avr", 2) == 4
    assert auto_workers("slow", 2) == 6 and auto_workers("not slowest", 2) == 6
    assert "3 workers a core" in what_runs("", False, 0)


def test_the_warm_up_writes_the_rewritten_copies_a_worker_finds(pytester):
    """tests/warm.py's collection before the workers: it writes a rewritten copy of each test
    file the run collects, and of the conftest above them, where pytest looks for it (the name
    and header it expects are pytest's own: a real collection made them); a touched file is
    current, an edited one stale; a run with fewer than MIN_STALE stale files starts none."""
    root = pytester.path
    pytester.makeconftest("")
    for d in ("sub", "other"):
        (root / d).mkdir()
        for i in range(MIN_STALE):
            (root / d / f"test_{d}{i}.py").write_text(f"def test_{i}():\n    assert {i} >= 0\n")
    assert len(stale(root)) == 2 * MIN_STALE + 1
    proc = start_collection(root, root, [root / "sub"])  # `pytest -n 6 sub`
    assert proc is not None and proc.wait(timeout=60) == 0
    assert stale(root) == sorted((root / "other").glob("test_*.py"))  # not this run's
    for f in [root / "conftest.py", *(root / "sub").glob("test_*.py")]:
        assert rewritten_copy(f).is_file(), f
    proc = start_collection(root, root)  # `pytest -n 6`: the rest
    assert proc is not None and proc.wait(timeout=60) == 0
    assert stale(root) == []
    assert start_collection(root, root) is None  # nothing to do
    src = root / "sub" / "test_sub0.py"
    os.utime(src)  # touched (a checkout): the copy is still of its source
    assert stale(root) == []
    src.write_text("def test_0():\n    assert 3\n")  # edited
    assert stale(root) == [src]
    assert start_collection(root, root) is None  # one file: the workers rewrite it sooner


def test_a_shared_fixture_s_tests_run_on_one_worker(pytester, monkeypatch):
    """The scheduling itself, two workers: a module fixture's tests (each parameter), and a
    document's blocks (their own mark), each on one worker, in order; the rest spread.
    xdist 3.8's own loadgroup spreads them on pytest 9.2 (xdist_groups.py says why)."""
    monkeypatch.setenv("PYTHONPATH", str(Path(__file__).parent))
    pytester.makepyfile(test_groups="""
        import os, time
        import pytest

        def log(*what):
            with open("ran.txt", "a") as f:
                print(*what, os.environ["PYTEST_XDIST_WORKER"], file=f)

        @pytest.fixture(scope="module", params=["a", "b"])
        def bench(request):
            return request.param

        @pytest.mark.parametrize("i", range(4))
        def test_shared(bench, i):
            time.sleep(0.05)
            log("RAN", bench)

        @pytest.mark.parametrize("i", [pytest.param(i, marks=pytest.mark.xdist_group("page"))
                                       for i in range(4)])
        def test_page(i):
            time.sleep(0.05)
            log("RAN page")

        @pytest.mark.parametrize("i", range(8))
        def test_free(i):
            time.sleep(0.05)
            log("RAN free")
    """)
    r = pytester.runpytest_subprocess("-p", "xdist_groups", "-n", "2", "--dist", "loadgroup",
                                      "-p", "no:cacheprovider")
    r.assert_outcomes(passed=20)
    ran: dict[str, set[str]] = {}
    for line in (pytester.path / "ran.txt").read_text().splitlines():
        if line.startswith("RAN "):
            _, what, worker = line.split()
            ran.setdefault(what, set()).add(worker)
    assert len(ran["a"]) == len(ran["b"]) == len(ran["page"]) == 1, ran
    assert len(ran["free"]) == 2, ran
