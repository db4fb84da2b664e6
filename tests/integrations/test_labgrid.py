"""The labgrid example (examples/labgrid/) through labgrid's own pytest plugin (``--lg-env``),
against ``lm629 sim serve --tcp`` as a NetworkSerialPort, in a virtual environment of its own.

labgrid depends on pyserial-labgrid, a fork of pyserial that installs into the same ``serial``
package: it must not replace the real pyserial of the main test environment.  So this test
runs labgrid in the environment named by ``LM629_LABGRID_PYTHON`` (its python), which
``.ci/run`` builds (``.venv-labgrid``: ``pip install -e '.[labgrid]' pytest``).  Without it
the test is skipped, with that reason in the run's summary.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from served import _sim_serve

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "labgrid"
PYTHON = os.environ.get("LM629_LABGRID_PYTHON", "")


def _labgrid_python() -> str:
    if not PYTHON or not Path(PYTHON).exists():
        pytest.skip("labgrid example not run: LM629_LABGRID_PYTHON does not name the python of a "
                    "labgrid venv (.ci/run builds .venv-labgrid: pip install -e '.[labgrid]' pytest)")
    return PYTHON


def test_labgrid_env_runs_the_example_against_sim_serve(tmp_path):
    python = _labgrid_python()
    shutil.copy(EXAMPLE / "test_lab_bench.py", tmp_path)
    with _sim_serve() as url:
        port = int(url.rsplit(":", 1)[1])
        env_yaml = (EXAMPLE / "env-sim.yaml").read_text()
        assert "port: 5629" in env_yaml
        (tmp_path / "env.yaml").write_text(env_yaml.replace("port: 5629", f"port: {port}"))
        env = {k: v for k, v in os.environ.items() if k not in ("LM629_PORT", "LM629_SIM_STRICT")}
        p = subprocess.run([python, "-m", "pytest", "-p", "no:cacheprovider", "-q", "--lg-env",
                            "env.yaml", "test_lab_bench.py"], cwd=tmp_path, capture_output=True,
                           text=True, timeout=300, env=env)
    assert p.returncode == 0, p.stdout + p.stderr
    assert re.search(r"\b2 passed\b", p.stdout), p.stdout
    # labgrid's serial fork is in that venv; the main venv keeps the real pyserial only
    q = subprocess.run([python, "-m", "pip", "list"], capture_output=True, text=True, timeout=120)
    assert "pyserial-labgrid" in q.stdout
    import importlib.metadata
    with pytest.raises(importlib.metadata.PackageNotFoundError):
        importlib.metadata.distribution("pyserial-labgrid")
    assert importlib.metadata.distribution("pyserial").version.startswith("3.")
