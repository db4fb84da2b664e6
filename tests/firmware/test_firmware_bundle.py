"""The firmware image shipped inside the package (``lm629 bridge flash``'s default) is the
firmware of this commit: rebuilt from ``firmware_bridge/`` and compared byte for byte."""

from __future__ import annotations

import subprocess
from pathlib import Path

from click.testing import CliRunner

from lm629_host.sim import harness
from lm629_host import data
from lm629_host.cli import main as cli


def test_the_shipped_image_is_the_firmware_of_this_commit(tmp_path):
    from firmware_helpers import require_firmware

    require_firmware()  # skips only without the toolchain; a broken build fails
    r = subprocess.run(["make", "-s", "-C", str(harness.FIRMWARE_DIR), f"B={tmp_path}",
                        "BAUD=115200", f"{tmp_path}/lm629_bridge.hex"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    built = (tmp_path / "lm629_bridge.hex").read_bytes()
    assert built.startswith(b":") and len(built) > 1000
    assert data.firmware_image().read_bytes() == built, (
        "lm629_host/data/lm629_bridge.hex is stale: run `make -C firmware_bridge bundle` and "
        "commit it")


def test_flash_defaults_to_the_shipped_image():
    image = data.firmware_image()
    assert image.is_file() and image.parent == Path(data.__file__).parent
    r = CliRunner().invoke(cli, ["bridge", "flash", "--port", "/dev/ttyACM0", "--dry-run"])
    assert r.exit_code == 0, r.output
    assert r.output.strip() == ("avrdude -p atmega328p -c arduino -P /dev/ttyACM0 -b 115200 -D "
                                f"-U flash:w:{image}:i")
