"""The screenshots of docs/panel.md: ``lm629 --port sim:// panel`` in Debian's chromium
(headless, selenium through chromedriver, as tests/panel drives it), a move under way and a
step test with the model's prediction drawn over it.

    python3 tools/panel_screenshots.py [--out docs]

Writes OUT/panel-move.png (mid-move: position, velocity, following error, the lights) and
OUT/panel-step.png (the move done, gains kp 30 applied and a 200-count step run).  Needs
chromium, chromium-driver (Debian) and selenium (the test extra).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run",
         "--window-size=1400,1000", "--hide-scrollbars")


def _wait(predicate, timeout: float = 15.0):
    end = time.monotonic() + timeout
    while not (value := predicate()):
        if time.monotonic() > end:
            raise SystemExit("the page did not get there in time")
        time.sleep(0.05)
    return value


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent.parent / "docs"))
    args = ap.parse_args()
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    out = Path(args.out)
    lm629 = shutil.which("lm629") or str(Path(sys.executable).parent / "lm629")
    server = subprocess.Popen([lm629, "--port", "sim://", "panel", "--listen", "127.0.0.1:0"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    profile = tempfile.mkdtemp(prefix="lm629-shots-")
    options = webdriver.ChromeOptions()
    options.binary_location = shutil.which("chromium") or "/usr/bin/chromium"
    for flag in FLAGS:
        options.add_argument(flag)
    options.add_argument(f"--user-data-dir={profile}")
    driver = webdriver.Chrome(service=Service(shutil.which("chromedriver") or "/usr/bin/chromedriver"),
                              options=options)
    try:
        assert server.stdout is not None
        url = server.stdout.readline().strip()
        driver.get(url)

        def el(i: str):
            return driver.find_element("id", i)

        def last(k: int):
            return driver.execute_script(f"return (window.panelState.axes['0'].last || [])[{k}]")

        def fill(i: str, text: str) -> None:
            el(i).clear()
            el(i).send_keys(text)

        _wait(lambda: driver.execute_script("return window.panelState.rows") > 50)
        fill("move-target", "8000")
        el("move").click()
        _wait(lambda: (last(1) or 0) > 5000)
        driver.save_screenshot(str(out / "panel-move.png"))
        print(f"wrote {out / 'panel-move.png'}")
        _wait(lambda: last(3) == 0 and (last(1) or 0) > 7900)
        fill("gain-kp", "30")
        el("apply").click()
        _wait(lambda: "30" in el("msg").text or el("msg").text)
        el("step").click()
        _wait(lambda: el("msg").text.startswith("target "), 30)
        time.sleep(0.5)
        driver.save_screenshot(str(out / "panel-step.png"))
        print(f"wrote {out / 'panel-step.png'}")
    finally:
        driver.quit()
        server.terminate()
        server.communicate(timeout=20)
        shutil.rmtree(profile, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
