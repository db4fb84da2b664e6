"""``lm629 --port sim:// panel`` in Debian's chromium (headless, selenium through
chromedriver): the page loads, its plots move during a move, a bad gain shows the command
line's one line, a step test draws the model's prediction over the measured response, a second
tab watches, Escape stops, a closed tab stops nothing.  One browser and one panel for the
module (a browser costs seconds); the tests run in order on the one simulated axis.

The numbers: the move's default velocity word 65536 is 1 count a sample; a sample is 2048
clocks of the 8 MHz chip, 256 us: 3906.25 counts/s (the page rounds to 0.1)."""

from __future__ import annotations

import re
import subprocess

import pytest

from lm629_host.chip.move import MoveRules
from panel_helpers import chromium, forward, last_row, message, panel, wait_for
from served import _console_script, _env

VELOCITY_CPS = 65536 / 65536 / (2048 / 8e6)  # counts/s of the default velocity word


@pytest.fixture(scope="module")
def page():
    with panel("sim://") as p, chromium() as driver:
        driver.get(p.url)
        yield driver, p


def _click(driver, element_id: str) -> None:
    driver.find_element("id", element_id).click()


def _type(driver, element_id: str, text: str) -> None:
    box = driver.find_element("id", element_id)
    box.clear()
    box.send_keys(text)


def _plotted(driver, series: int, plot: int = 0) -> list:
    """The values the axis's plot ``plot`` (0 position, 1 velocity, 2 following error) holds
    in series ``series`` (0: time)."""
    return driver.execute_script(
        f"return window.panelState.axes['0'].plots[{plot}].data[{series}]")


def test_page_loads(page):
    driver, p = page
    assert driver.title == "lm629 panel"
    assert wait_for(lambda: driver.find_element("id", "role").text == "this tab commands",
                    what="the commanding role")
    assert driver.find_element("css selector", "#axis-0 h2").text == "axis 0"
    assert len(driver.find_elements("css selector", "#axis-0 .status .light")) == 8
    assert len(driver.find_elements("css selector", "#axis-0 .signals .light")) == 16
    assert driver.find_element("id", "source").text.startswith("samples: far-side recording")
    assert wait_for(lambda: len(_plotted(driver, 0)) > 10, what="plotted rows")
    assert driver.find_element("id", "failsafe").text == "none on this link"


def test_plots_move_during_a_move(page):
    driver, _p = page
    assert last_row(driver)[:2] == [0, 0]
    _type(driver, "move-target", "4000")
    _click(driver, "move")
    assert wait_for(lambda: message(driver), what="an answer").startswith("moving to 4000 counts")
    # mid-move: the plotted actual position has left 0 and not yet arrived, within 5 s
    mid = wait_for(lambda: 500 < (_plotted(driver, 2) or [0])[-1] < 3500, timeout=5,
                   what="a plotted position mid-move")
    assert mid
    # the trapezoid's top speed, plotted: the desired velocity at the velocity word
    wait_for(lambda: max(_plotted(driver, 1, plot=1)) >= round(VELOCITY_CPS, 1),
             what="the top speed plotted")
    assert max(_plotted(driver, 1, plot=1)) == round(VELOCITY_CPS, 1)
    # arrived: the plots and lights show it at rest where the command line's own move of the
    # same fresh simulated chip (reset, kp = 20) comes to rest
    cli = subprocess.run([_console_script(), "--port", "sim://", "move", "4000"],
                         capture_output=True, text=True, timeout=60, env=_env())
    rest = int(re.search(r"^done: at (-?\d+) counts", cli.stdout, re.M).group(1))
    assert abs(rest - 4000) <= MoveRules().tolerance
    wait_for(lambda: last_row(driver)[1] == rest and last_row(driver)[3] == 0,
             what=f"the axis at rest on {rest}")
    # the readout's velocity: the plotted actual velocity's last number (a row with none, the
    # first after a command, is never shown as "null")
    readout = driver.find_element("css selector", "#axis-0 .readout").text
    assert re.fullmatch(rf"desired 4000\s+actual {rest}\s+error {4000 - rest}\s+velocity 0 counts/s",
                        readout), readout
    velocities = _plotted(driver, 2, plot=1)
    assert None in velocities  # the first row after the move's command: nothing to measure from
    lit = [e.text for e in driver.find_elements("css selector", "#axis-0 .status .light.on")]
    assert "trajectory complete" in lit and "motor off" not in lit
    errors = _plotted(driver, 1, plot=2)
    assert max(errors) > 0  # a following error while it moved, plotted


def test_bad_gain_shows_the_command_lines_one_line(page):
    driver, _p = page
    cli = subprocess.run([_console_script(), "--port", "sim://", "filter", "--kp", "40000"],
                         capture_output=True, text=True, timeout=60, env=_env())
    assert cli.returncode == 2
    line = cli.stderr.strip().splitlines()[-1]
    assert line.startswith("lm629: Invalid value for --kp: kp=40000")
    _type(driver, "gain-kp", "40000")
    _click(driver, "apply")
    wait_for(lambda: "40000" in message(driver), what="the answer")
    assert message(driver) == line
    assert "error" in driver.find_element("id", "msg").get_attribute("class")
    _type(driver, "gain-kp", "30")
    _click(driver, "apply")
    assert wait_for(lambda: "kp=30" in message(driver) or "loaded" in message(driver).lower(),
                    what="the gains applied"), message(driver)


def test_step_test_draws_the_prediction(page):
    driver, _p = page
    start = last_row(driver)[0]  # a step goes from the desired position
    _type(driver, "step-distance", "200")
    _type(driver, "step-time", "0.3")
    _click(driver, "step")
    wait_for(lambda: message(driver).startswith("target "), timeout=20, what="the step's summary")
    assert message(driver).startswith(f"target {start + 200} counts")
    data = driver.execute_script("return window.panelState.stepPlot.data")
    t, desired, measured, predicted = data
    assert len(t) == len(measured) == len(predicted) >= 290  # 0.3 s at 1 ms
    assert desired[-1] == start + 200
    tol = MoveRules().tolerance
    assert abs(measured[-1] - (start + 200)) <= tol and abs(predicted[-1] - (start + 200)) <= tol
    # the simulated motor and the tuner's model are the same physics and the same filter
    # arithmetic (the predictor is within a count of the chip's): the curves agree within
    # that count, a count for a row up to half a sample off the model's samples (the step
    # peaks under 2 counts a sample) and a count for where in a count the shaft rested
    assert max(abs(m - q) for m, q in zip(measured, predicted)) <= 3
    assert driver.find_element("id", "step-note").text == \
        "prediction: the simulated motor's numbers"


def test_second_tab_watches_escape_stops_closed_tab_stops_nothing(page):
    driver, _p = page
    first = driver.current_window_handle
    url = driver.current_url
    driver.switch_to.new_window("tab")
    driver.get(url)
    second = driver.current_window_handle
    wait_for(lambda: driver.find_element("id", "role").text.startswith("this tab watches"),
             what="the watching role")
    start = last_row(driver)[0]
    _type(driver, "move-target", "-20000")
    _click(driver, "move")
    wait_for(lambda: message(driver), what="an answer")
    assert message(driver).startswith("lm629: another tab commands this bench (opened at ")
    assert last_row(driver)[0] == start  # nothing moved
    # the first tab moves; Escape (in the watching tab) stops it: a stop comes from any tab
    driver.switch_to.window(first)
    _type(driver, "move-target", "-20000")
    _click(driver, "move")
    wait_for(lambda: last_row(driver)[1] < start - 500, what="the move under way")
    driver.switch_to.window(second)
    driver.find_element("tag name", "body").send_keys("\ue00c")  # Escape
    wait_for(lambda: message(driver) == "abrupt stop sent", what="the stop's answer")
    wait_for(lambda: last_row(driver)[3] == 0, what="the axis at rest")
    held = last_row(driver)[1]
    assert -20000 < held < start - 500
    # the first tab starts a move and closes: the move goes on to its target
    driver.switch_to.window(first)
    _type(driver, "move-target", str(held + 3000))
    _click(driver, "move")
    wait_for(lambda: message(driver).startswith(f"moving to {held + 3000} counts"),
             what="the move's answer")  # this move's: the tab showed the last move's before
    driver.close()
    driver.switch_to.window(second)
    wait_for(lambda: driver.find_element("id", "role").text == "this tab commands",
             what="the watching tab commanding")
    wait_for(lambda: abs(last_row(driver)[1] - (held + 3000)) <= MoveRules().tolerance
             and last_row(driver)[3] == 0,
             what="the closed tab's move ended on its target")


def test_through_a_port_forward(page):
    """Loaded through a forward from another port (what ``ssh -L 9000:127.0.0.1:8629`` gives
    the browser): the page's relative URLs reach the panel, its Host and Origin name
    ``localhost:PORT`` and pass, and its commands (a stop: from any tab) go through."""
    driver, p = page
    with forward(p) as port:
        driver.switch_to.new_window("tab")
        driver.get(f"http://localhost:{port}/")
        wait_for(lambda: len(_plotted(driver, 0)) > 10, what="rows through the forward")
        driver.find_element("tag name", "body").send_keys("\ue00c")  # Escape
        wait_for(lambda: message(driver), what="the stop's answer")
        assert message(driver) == "abrupt stop sent"
        driver.close()
        driver.switch_to.window(driver.window_handles[0])


def test_exposed_with_its_token_in_the_address(page):
    """Beyond the loopback names (127.0.0.2 here: still this machine) with --expose: the
    address carries the token, and the page opened from it works whole (its files, its rows,
    its commands)."""
    driver, _p = page
    with panel("sim://", "--expose", listen="127.0.0.2:0") as exposed:
        assert "/?token=" in exposed.url
        driver.switch_to.new_window("tab")
        driver.get(exposed.url)
        wait_for(lambda: len(_plotted(driver, 0)) > 10, what="rows on the exposed panel")
        assert driver.find_element("id", "role").text == "this tab commands"
        _click(driver, "stop")
        wait_for(lambda: message(driver), what="the stop's answer")
        assert message(driver) == "abrupt stop sent"
        driver.close()
        driver.switch_to.window(driver.window_handles[0])
