"""The link failsafe on a served bench: one ``lm629 sim serve`` far end on a pty, each client
its own process, killed or cut off as a lab PC would be.

The bench, the client and the watch on the shafts are tools/bench_failsafe.py's (the same
code measures the figures of docs/performance.md): the server runs in this process so that
its RestWatch sees, on the simulator's clock, when each shaft last moved; the clients are
separate processes on ``serial://LINK``.  The bound: failsafe (0.5 s) + the same abrupt stop
sent by a live host (measured on the same model) + 20 ms, from the host's last frame (the trip
report: the bridge's time of the trip minus the silence).  The served bench runs in real
time, so each test waits about a second of wall time for the bridge's timer.
"""

from __future__ import annotations

import signal
import sys
import time
from pathlib import Path

import pytest

from lm629_host.sim.harness import toolchain_missing
from served import _env

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
from bench_failsafe import (
    FAR_ENDS,
    SPEED,
    client,
    death_to_rest,
    lm629,
    reference_stop_s,
    served,
    status,
)

#: timed behaviour a busy lab PC must keep: CI runs these beside two CPU hogs (-m under_load)
pytestmark = pytest.mark.under_load


def _far_end(far_end: str) -> str:
    if far_end.startswith("firmware") and toolchain_missing():
        pytest.skip(f"AVR toolchain missing ({', '.join(toolchain_missing())})")
    return far_end


@pytest.mark.parametrize("far_end", FAR_ENDS)
def test_a_killed_host_has_every_axis_at_rest_and_the_next_process_is_told(tmp_path, far_end):
    took, st, err = death_to_rest(tmp_path, _far_end(far_end), env=_env())
    assert took is not None and 0.5 <= took <= 0.5 + reference_stop_s("abrupt") + 0.020, took
    assert "the bridge stopped cs 0, cs 1 (abrupt stop) after the host was silent" in err
    assert st["failsafe"]["trip"]["cs"] == [0, 1]
    for row in st["axes"]:
        assert row["desired_velocity"] == 0 and row["real_velocity"] == 0
        assert "MOTOR_OFF" not in row["status_flags"]  # the PID holds
    assert st["failsafe"]["armed_s"] == 0.5 and not st["failsafe"]["tripped"]  # acknowledged


def test_a_killed_host_with_the_failsafe_off_leaves_the_axes_turning(tmp_path):
    took, st, _ = death_to_rest(tmp_path, "python", "?failsafe=0", env=_env())
    assert took is None and st["failsafe"]["trip"] is None
    # still commanded at full speed, and turning: the encoder's count per sample at 2.0
    # counts/sample reads 1..3 at the moment a real-time status catches it (servo ripple)
    assert all(row["desired_velocity"] == SPEED and abs(row["real_velocity"] - 2) <= 1
               for row in st["axes"])


@pytest.mark.parametrize("far_end", ["python", "firmware+uno"])
def test_a_pulled_cable_trips_the_bridge(tmp_path, far_end):
    with served(tmp_path, _far_end(far_end)) as (server, watch):
        proc = client(server.link, "unplug", env=_env())  # alive, nothing reaches the bridge
        watch.start()
        assert watch.wait_rest()
        st, err = status(server.link, _env())
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    assert st["failsafe"]["trip"]["cs"] == [0, 1], err


@pytest.mark.parametrize("far_end", ["python", "firmware"])
def test_a_clean_close_after_move_no_wait_leaves_the_axis_moving(tmp_path, far_end):
    with served(tmp_path, _far_end(far_end)) as (server, _watch):
        link = server.link
        for args in (("reset",), ("filter", "--kp", "20", "--ds", "1"),
                     ("move", "200000", "--no-wait")):
            p = lm629(link, *args, env=_env())
            assert p.returncode == 0, p.stderr
        time.sleep(0.8)  # past the failsafe's 0.5 s on the bridge's clock
        a = status(link, _env())[0]
        time.sleep(0.1)
        b, err = status(link, _env())
    assert a["failsafe"]["trip"] is None and b["failsafe"]["trip"] is None, err
    assert b["axes"][0]["real_position"] > a["axes"][0]["real_position"] > 0


@pytest.mark.parametrize("far_end", ["python", "firmware"])
def test_a_with_block_raising_mid_move_leaves_the_axes_at_rest(tmp_path, far_end):
    with served(tmp_path, _far_end(far_end)) as (server, _watch):
        proc = client(server.link, "raise", env=_env())
        _, err = proc.communicate(timeout=30)
        assert proc.returncode == 1 and "ZeroDivisionError" in err
        st, err = status(server.link, _env())
    assert st["failsafe"]["trip"] is None, err  # the host stopped them, not the bridge
    for row in st["axes"]:
        assert row["desired_velocity"] == 0 and row["real_velocity"] == 0
        assert "MOTOR_OFF" not in row["status_flags"]  # the PID holds
