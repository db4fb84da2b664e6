"""Tests that share something wider than a test stay on one xdist worker, one after the
other; every other test goes to whichever worker is free (``-n N --dist loadgroup``, set in
pyproject's addopts; docs/testing.md, "The project's own suite").  A pytest plugin of the
suite's (tests/conftest.py loads it), so a new test file needs no entry anywhere: its group
follows from the fixtures it uses, or its own ``xdist_group`` mark."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import pytest


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        group = shared_fixture_group(item, config.rootpath)
        if group:
            item.add_marker(pytest.mark.xdist_group(group))


def shared_fixture_group(item: pytest.Item, root: Path) -> str | None:
    """The xdist group of a test that shares a fixture wider than itself (module, class,
    package scope: a served bench, a built wheel): every test of that fixture (and parameter)
    on one worker, one after the other, so it is set up once per run (``--dist loadgroup``).
    A test without one runs wherever a worker is free.  A test's own ``xdist_group`` mark wins
    (the docs blocks: one group per document, tests/test_docs.py)."""
    if item.get_closest_marker("xdist_group") is not None:
        return None
    # pytest has no public view of a test's fixture definitions at collection time
    info = getattr(item, "_fixtureinfo", None)
    params = getattr(getattr(item, "callspec", None), "params", {})
    shared = []
    for name in sorted(getattr(item, "fixturenames", ())):
        defs = info.name2fixturedefs.get(name) if info is not None else None
        if defs and defs[-1].scope in ("module", "class", "package"):
            shared.append(f"{name}={params[name]}" if name in params else name)
    if not shared:
        return None
    return f"{item.path.relative_to(root)}:{','.join(shared)}"


#: the key of xdist's ``workerinput`` that names the directory each worker writes its groups to
GROUPS_KEY = "lm629_groups_dir"


def write_groups(items: list[pytest.Item], where: Path, worker: str) -> None:
    """A worker's {test id: xdist group}, for :class:`GroupScheduling` in the controller
    (written whole, then renamed: the controller never reads half a file)."""
    table = {i.nodeid: "_".join(sorted(str(m.args[0] if m.args else m.kwargs.get("name"))
                                      for m in i.iter_markers("xdist_group")))
             for i in items if i.get_closest_marker("xdist_group") is not None}
    part = where / f"{worker}.part"
    part.write_text(json.dumps(table))
    part.replace(where / f"{worker}.json")


def group_scheduling(config: pytest.Config, log, where: Path):
    """``--dist loadgroup`` that reads the groups from the workers' tables rather than from
    the test ids: xdist 3.8 appends ``@group`` to an item's id through a field pytest 9.2 no
    longer reads (a known pytest-xdist bug, open upstream), and its loadgroup then spreads a
    group's tests over the workers without a word.  The scheduling is xdist's own (one unit a time to the
    first worker with room, the largest units first); only the units come from here."""
    from xdist.scheduler import LoadScopeScheduling

    class GroupScheduling(LoadScopeScheduling):
        _table: dict[str, str] | None = None

        def _split_scope(self, nodeid: str) -> str:
            if self._table is None:  # every worker has collected: each wrote the same table
                tables = sorted(where.glob("*.json"))
                if not tables:
                    raise RuntimeError(f"no worker wrote its xdist groups into {where}")
                self._table = json.loads(tables[0].read_text())
            group = self._table.get(nodeid)
            return f"group:{group}" if group else nodeid

    return GroupScheduling(config, log)


#: the controller's directory for the workers' group tables (removed at the run's end)
_GROUPS: list[tempfile.TemporaryDirectory] = []


def _groups_dir(config: pytest.Config) -> Path:
    if not _GROUPS:
        _GROUPS.append(tempfile.TemporaryDirectory(prefix="lm629-xdist-groups-"))
        config.add_cleanup(_GROUPS[0].cleanup)
    return Path(_GROUPS[0].name)


@pytest.hookimpl(optionalhook=True)  # xdist's hooks: nothing to do without xdist
def pytest_configure_node(node) -> None:
    """xdist, in the controller, for each worker: where it writes its groups."""
    node.workerinput[GROUPS_KEY] = str(_groups_dir(node.config))


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log):
    if config.getvalue("dist") == "loadgroup":
        return group_scheduling(config, log, _groups_dir(config))
    return None


@pytest.hookimpl(tryfirst=True)  # before xdist's own, which sends the collection to the controller
def pytest_collection_finish(session: pytest.Session) -> None:
    where = getattr(session.config, "workerinput", {}).get(GROUPS_KEY)
    if where:
        write_groups(session.items, Path(where), session.config.workerinput["workerid"])
