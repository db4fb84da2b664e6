"""Files shipped inside the package, so that an installed wheel needs no checkout: the bridge
firmware image (``lm629 bridge flash``'s default) and the FT232H udev rule (``lm629 udev``).

``lm629_bridge.hex`` is the 115200-baud build of ``firmware_bridge/``, made by ``make -C
firmware_bridge bundle``; a test rebuilds it from the sources and compares, so the shipped
image is never older than the firmware in the same commit.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

#: the bridge firmware image (Intel hex, ATmega328P at 16 MHz, 115200 baud)
FIRMWARE_HEX = "lm629_bridge.hex"
#: the udev rule that lets the plugdev group open FT232H adapters (USB 0403:6014)
UDEV_RULE = "99-lm629-ft232h.rules"
#: where udev reads local rules
UDEV_RULES_DIR = "/etc/udev/rules.d"


def path(name: str) -> Path:
    """The file ``name`` of this folder, on disk (a wheel is installed unzipped)."""
    return Path(str(files(__name__).joinpath(name)))


def firmware_image() -> Path:
    return path(FIRMWARE_HEX)


def udev_rule() -> Path:
    return path(UDEV_RULE)


def udev_install_commands() -> list[str]:
    """The shell commands that install the udev rule from wherever this package is."""
    return [f"sudo cp {udev_rule()} {UDEV_RULES_DIR}/",
            "sudo udevadm control --reload-rules && sudo udevadm trigger",
            "sudo usermod -aG plugdev $USER   (then log out and in again; replug the adapter)"]


__all__ = ["FIRMWARE_HEX", "UDEV_RULE", "UDEV_RULES_DIR", "firmware_image", "path", "udev_rule",
           "udev_install_commands"]
