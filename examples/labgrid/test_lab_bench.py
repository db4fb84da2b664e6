"""A lab test run by labgrid's pytest plugin: `pytest --lg-env env-sim.yaml` (docs/testing.md).

The LM629Driver gives the chip; labgrid gives the target, the place and its lock.  Figures:
kp = 20 leaves a P-only dead band of 256 / 20 = 12.8 counts (AN-706 5.2.4), inside the
default tolerance of 20 counts.
"""

from lm629_host import Status


def test_the_driver_gives_a_reset_chip(target):
    chip = target.get_driver("LM629Driver").chip()
    assert chip.read_status() & Status.MOTOR_OFF  # 80 or C0 after reset (AN-706 4.4.1)


def test_a_move_on_the_labgrid_bench(target):
    drv = target.get_driver("LM629Driver")
    chip = drv.chip()
    chip.load_filter(kp=20, kd=200)
    chip.update_filter()
    result = chip.move_to(2000, velocity=4 * 65536, acceleration=3277).wait()
    assert abs(result.error) <= 20
    assert len(drv.get_board(reset=False).axes) >= 1
