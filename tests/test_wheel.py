"""A wheel built from this tree works without the checkout: installed into a fresh virtual
environment in a folder outside the checkout, it runs a bring-up on the bundled simulator,
points ``bridge flash`` at the firmware image it carries, and shows the udev commands with the
rule's installed path.

The plugin comes with it: the example lab file runs there under plain ``python -m pytest``.

The fresh environment gets the package's dependencies (click, pyserial, pyusb) from the test
environment's site-packages as a plain path entry, so that nothing is downloaded and the
editable install of this checkout (a ``.pth`` hook there, which a plain path entry does not
run) cannot be what is imported: the test checks where ``lm629_host`` came from.
"""

from __future__ import annotations

import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("wheel")
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps",
                        "--no-build-isolation", "-w", str(tmp / "dist"), str(ROOT)],
                       capture_output=True, text=True, cwd=tmp)
    assert r.returncode == 0, r.stdout + r.stderr
    wheel = next((tmp / "dist").glob("lm629_host-*.whl"))
    venv = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    py = venv / "bin" / "python"
    site = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_path("
                                "'purelib'))"], capture_output=True, text=True,
                               check=True).stdout.strip())
    r = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps",
                        "--target", str(site), str(wheel)], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    (site / "deps.pth").write_text(sysconfig.get_path("purelib") + "\n")
    away = tmp / "bench"
    away.mkdir()
    return py, site, away


def run(installed, *args: str) -> subprocess.CompletedProcess[str]:
    py, _, away = installed
    return subprocess.run([str(py), "-m", "lm629_host", *args], capture_output=True,
                          text=True, cwd=away, timeout=120,
                          env={"PATH": "/usr/bin:/bin", "HOME": str(away)})


def test_the_installed_package_is_the_wheel(installed):
    py, site, away = installed
    r = subprocess.run([str(py), "-c", "import lm629_host; print(lm629_host.__file__)"],
                       capture_output=True, text=True, cwd=away, check=True)
    assert Path(r.stdout.strip()).is_relative_to(site)
    assert not Path(r.stdout.strip()).is_relative_to(ROOT)


def test_bringup_on_the_simulator(installed):
    r = run(installed, "bringup", "--yes")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "verdict: PASS, every step" in r.stdout


def test_bridge_flash_points_at_the_shipped_image(installed):
    _, site, _ = installed
    image = site / "lm629_host" / "data" / "lm629_bridge.hex"
    assert image.is_file() and image.read_bytes() == (
        ROOT / "lm629_host" / "data" / "lm629_bridge.hex").read_bytes()
    r = run(installed, "bridge", "flash", "--dry-run", "--port", "/dev/ttyACM0")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().endswith(f"-U flash:w:{image}:i")


def test_udev_commands_name_the_installed_rule(installed):
    _, site, _ = installed
    rule = site / "lm629_host" / "data" / "99-lm629-ft232h.rules"
    assert rule.is_file()
    r = run(installed, "udev")
    assert r.returncode == 0, r.stderr
    assert f"sudo cp {rule} /etc/udev/rules.d/" in r.stdout
    assert run(installed, "udev", "--path").stdout.strip() == str(rule)


def test_a_lab_test_file_runs_under_plain_pytest(installed):
    """The pytest plugin comes with the wheel (entry point pytest11): the example lab file
    runs in a folder of its own with plain ``python -m pytest``, no conftest, no -p."""
    import shutil

    py, site, away = installed
    lab = away / "lab"
    lab.mkdir()
    for name in ("rig.py", "test_rig.py"):
        shutil.copy(ROOT / "examples" / "lab" / name, lab / name)
    r = subprocess.run([str(py), "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider"],
                       capture_output=True, text=True, cwd=lab, timeout=300,
                       env={"PATH": "/usr/bin:/bin", "HOME": str(away)})
    assert r.returncode == 0, r.stdout + r.stderr
    assert "6 passed, 1 skipped" in r.stdout
    assert "lm629_hardware: needs a real board (--lm629-port is sim://, simulated)" in r.stdout
    r = subprocess.run([str(py), "-c", "import lm629_host.integrations.pytest_plugin as p; print(p.__file__)"],
                       capture_output=True, text=True, cwd=lab, check=True)
    assert Path(r.stdout.strip()).is_relative_to(site)


@pytest.mark.skipif(__import__("shutil").which("sigrok-cli") is None,
                    reason="sigrok-cli is not installed (.ci/run installs it)")
@pytest.mark.parametrize("where", ["default", "--dir"])
def test_sigrok_install_then_sigrok_cli_decodes_the_simulators_vcd(installed, where):
    """``lm629 --vcd`` writes the simulated bus, ``lm629 sigrok install`` puts the wheel's
    decoder where sigrok looks (the user's decoders directory under HOME, or ``--dir``), and
    sigrok's own tool decodes the reset's MSKI and RSTI from it."""
    from lm629_host.sigrok import FILES, failed

    _, site, away = installed
    vcd = away / f"reset-{where}.vcd"
    r = run(installed, "--vcd", str(vcd), "reset")
    assert r.returncode == 0, r.stdout + r.stderr
    args = ("sigrok", "install") + (("--dir", str(away / "decoders")) if where == "--dir" else ())
    r = run(installed, *args)
    assert r.returncode == 0, r.stdout + r.stderr
    target = (away / "decoders" if where == "--dir"
              else away / ".local" / "share" / "libsigrokdecode" / "decoders") / "lm629"
    assert f"installed the lm629 decoder in {target}" in r.stdout
    for name in FILES:
        assert (target / name).read_bytes() == (site / "lm629_host" / "sigrok" / "lm629" /
                                                name).read_bytes()
    env = {"PATH": "/usr/bin:/bin", "HOME": str(away)}
    if where == "--dir":
        env["SIGROKDECODE_DIR"] = str(target.parent)
    r = subprocess.run(["sigrok-cli", "-I", "vcd", "-i", str(vcd), "-P", "lm629",
                        "-A", "lm629=commands"], capture_output=True, text=True, cwd=away,
                       env=env, timeout=120)
    assert not failed(r.returncode, r.stderr), r.stderr
    assert r.stdout.splitlines() == ["lm629-1: MSKI 0000: enable none",
                                     "lm629-1: RSTI 0000: keep none"]


def test_the_panel_serves_its_page_and_plot_library_from_the_wheel(installed):
    """`lm629 panel` from the installed wheel: the page and uPlot (with its licence) come from
    the package's files: nothing fetched, nothing built."""
    import signal
    import urllib.request

    py, site, away = installed
    static = site / "lm629_host" / "panel" / "static"
    assert (static / "uPlot.LICENSE").read_text().startswith("The MIT License")
    proc = subprocess.Popen([str(py), "-m", "lm629_host", "panel", "--listen", "127.0.0.1:0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=away,
                            env={"PATH": "/usr/bin:/bin", "HOME": str(away)})
    try:
        url = proc.stdout.readline().strip()
        assert url.startswith("http://127.0.0.1:"), url + proc.stderr.read()
        page = urllib.request.urlopen(url, timeout=30).read().decode()
        assert 'src="static/uPlot.iife.min.js"' in page and "cdn" not in page.lower()
        served = urllib.request.urlopen(url + "static/uPlot.iife.min.js", timeout=30).read()
        assert served == (ROOT / "lm629_host" / "panel" / "static" / "uPlot.iife.min.js").read_bytes()
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=30)
    assert proc.returncode == 130
