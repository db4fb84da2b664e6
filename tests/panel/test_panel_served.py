"""``lm629 panel`` on a served bench (``lm629 sim serve``: a far end that keeps its state, in
real time, from separate processes): the stop button stops the axis mid-move, and the panel
ended by SIGTERM mid-move stops it too; a separate ``lm629 status`` afterwards sees the shaft
at rest short of the target.  One browser for the module."""

from __future__ import annotations

import signal
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


@pytest.mark.parametrize("far_end", ["python", "firmware+uno"])
def test_stop_button_stops_a_served_bench_mid_move(tmp_path, driver, far_end):
    """The Python far end, and the compiled firmware in simavr behind an Uno's USB chip (its
    4.096 ms flush tick between the panel and the bridge)."""
    with serve(tmp_path, far_end) as bench:
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
            # the panel holds the bench's port, as any client does: another command is
            # refused (exit 3, saying why) and never ends the panel's link
            other = bench.run("status")
            assert other.returncode == 3 and "in use by another program" in other.stderr
            assert p.proc.poll() is None
            code, err = p.end()
        assert code == 143 and err.strip().splitlines()[-1] == "lm629: terminated (SIGTERM)", err
        _at_rest_short_of_target(bench, 2000)


def test_a_trip_shows_at_once_and_is_acknowledged_from_the_page(tmp_path, driver):
    """The panel's process paused (SIGSTOP, a host that stalls) 1.5 s mid-move, past the
    served link's 0.5 s failsafe: the bridge stops the axis; woken, the page shows the trip
    (the failsafe box red, a bar over the page) and its Acknowledge button runs `lm629 clear`;
    the panel itself runs on."""
    with serve(tmp_path, "python") as bench:
        bench.ready()
        with panel(f"serial://{bench.link}") as p:
            driver.get(p.url)
            wait_for(lambda: driver.find_element("id", "failsafe").text == "armed: 500 ms",
                     what="the armed failsafe")
            box = driver.find_element("id", "move-target")
            box.clear()
            box.send_keys(str(FAR))
            driver.find_element("id", "move").click()
            wait_for(lambda: last_row(driver)[1] > 1000, what="the axis under way")
            p.proc.send_signal(signal.SIGSTOP)
            time.sleep(1.5)
            p.proc.send_signal(signal.SIGCONT)
            woke = time.monotonic()
            wait_for(lambda: "tripped" in driver.find_element("id", "failsafe").get_attribute("class"),
                     what="the trip shown")
            shown = time.monotonic() - woke
            text = driver.find_element("id", "failsafe").text
            assert text.startswith("the bridge stopped axis 0 (cs 0)"), text
            bar = driver.find_element("id", "fault")
            assert bar.is_displayed() and bar.text == "failsafe trip: " + text
            wait_for(lambda: last_row(driver)[3] == 0, what="the axis stopped by the bridge")
            driver.find_element("id", "clear").click()
            wait_for(lambda: message(driver).startswith("acknowledged: "), what="the clear")
            wait_for(lambda: driver.find_element("id", "failsafe").text == "armed: 500 ms",
                     what="the failsafe armed again")
            assert not driver.find_element("id", "fault").is_displayed()
            assert not driver.find_element("id", "clear").is_displayed()
            assert p.proc.poll() is None
            print(f"trip shown {shown:.2f} s after the panel woke")
        st = bench.status()
        assert st["failsafe"]["trip"] is None
        assert st["real_position"] < FAR // 2


def test_a_bench_lost_under_the_panel_ends_it_in_one_line(tmp_path):
    """The far end gone (the served bench killed: a board unplugged): the page is told at
    once, and the panel ends with the command line's line for it, exit 3."""
    with serve(tmp_path, "python") as bench:
        bench.ready()
        with panel(f"serial://{bench.link}") as p:
            token = p.page_token()
            with events(p, token) as stream:
                next(stream)
                bench.server.send_signal(signal.SIGKILL)
                fault = next(m for m in stream if m["type"] == "fault")
            code = p.proc.wait(timeout=30)
            err = p.proc.stderr.read()
        bench.link.unlink()  # the killed server could not remove its link
    assert code == 3, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("lm629: error: ") and "was the board unplugged?" in last, err
    assert fault["text"] == "the bench stopped: " + last[len("lm629: "):]
