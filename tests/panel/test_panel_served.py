"""``lm629 panel`` on a served bench (``lm629 sim serve``: a far end that keeps its state, in
real time, from separate processes): the stop button stops the axis mid-move, and the panel
ended by SIGTERM mid-move stops it too; a separate ``lm629 status`` afterwards sees the shaft
at rest short of the target.  One browser for the module."""

from __future__ import annotations

import time

import pytest

from lm629_host.chip.move import MoveRules
from panel_helpers import chromium, command, events, last_row, message, panel, wait_for
from served import serve

#: a move that takes about 25 s at the default velocity (3906.25 counts/s): stopped long before
FAR = 100_000


@pytest.fixture(scope="module")
def driver():
    with chromium() as d:
        yield d


def _at_rest_short_of_target(bench, before: int) -> dict:
    """The served bench's status from a separate process: not moving, short of FAR."""
    first = bench.status()
    time.sleep(0.3)  # real time on a served bench: it would have moved on by now
    st = bench.status()
    assert st["real_position"] == first["real_position"], (first, st)
    assert before < st["real_position"] < FAR // 2
    assert "TRAJECTORY_COMPLETE" in st["status_flags"]
    return st


def test_stop_button_stops_a_served_bench_mid_move(tmp_path, driver):
    with serve(tmp_path, "python") as bench:
        bench.ready()
        with panel(f"serial://{bench.link}") as p:
            driver.get(p.url)
            wait_for(lambda: driver.find_element("id", "role").text == "this tab commands",
                     what="the commanding role")
            assert driver.find_element("id", "source").text.startswith("samples: far-side")
            box = driver.find_element("id", "move-target")
            box.clear()
            box.send_keys(str(FAR))
            driver.find_element("id", "move").click()
            wait_for(lambda: last_row(driver)[1] > 2000, what="the axis under way")
            driver.find_element("id", "stop").click()
            wait_for(lambda: message(driver) == "abrupt stop sent", what="the stop's answer")
            wait_for(lambda: last_row(driver)[3] == 0, what="a plotted stop")
            held = last_row(driver)[0]  # an abrupt stop holds the desired position there
            lit = [e.text for e in driver.find_elements("css selector", "#axis-0 .status .light.on")]
            assert "trajectory complete" in lit and "motor off" not in lit  # abrupt: holding
            code, err = p.end()
        assert code == 143, err
        st = _at_rest_short_of_target(bench, 2000)
        assert st["desired_position"] == held  # where the page showed it stopped
        assert abs(st["real_position"] - held) <= MoveRules().tolerance  # and holds
        assert "MOTOR_OFF" not in st["status_flags"]


def test_panel_ended_mid_move_stops_the_served_axis(tmp_path):
    """The panel's own end (SIGTERM here: a closed terminal, a service manager) during a
    move: the axis is stopped before the process exits, exit 143 with the one line."""
    with serve(tmp_path, "python") as bench:
        bench.ready()
        with panel(f"serial://{bench.link}") as p:
            token = p.page_token()
            with events(p, token) as stream:
                hello = next(stream)
                status, answer = command(p, token, {"cmd": "move", "target": str(FAR),
                                                    "client": hello["client"]})
                assert answer["ok"], answer
                for m in stream:
                    if m["type"] == "rows" and m["rows"][-1][2] > 2000:
                        break
            code, err = p.end()
        assert code == 143 and err.strip().splitlines()[-1] == "lm629: terminated (SIGTERM)", err
        _at_rest_short_of_target(bench, 2000)
