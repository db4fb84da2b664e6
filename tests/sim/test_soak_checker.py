"""The exactly-once checker of the fault soak (``sim.faults.check_record``) decides exactly.

A record the soak made (run 0 of ``tools/fault_soak.py --runs 2 --n 5000 --rate 0.01``,
Python far end): calls SBPA 5805 (returned), RDRP (raised), SBPA 5807 (raised), RDRP (returned),
SBPA 5809 (returned); the chip's record SBPA 5805, RDRP, SBPA 5809.  That is consistent (the
failed RDRP and SBPA 5807 never ran, the returned RDRP did); a checker that matches greedily
gives the one RDRP to the failed call and reports the returned one lost.
"""

from __future__ import annotations

import pytest

from lm629_host.sim.faults import check_record
from lm629_host.bus.opcodes import Cmd

RDRP = (int(Cmd.RDRP), ())


def sbpa(pos: int):
    return (int(Cmd.SBPA), ((pos >> 16) & 0xFFFF, pos & 0xFFFF))


def test_issue16_record_is_consistent():
    calls = [(sbpa(5805), True), (RDRP, False), (sbpa(5807), False), (RDRP, True),
             (sbpa(5809), True)]
    history = [sbpa(5805), RDRP, sbpa(5809)]
    assert check_record(history, calls) == (0, 2)  # both failed calls did not run


def test_failed_call_that_ran_is_counted():
    calls = [(RDRP, False), (sbpa(1), True), (RDRP, True)]
    assert check_record([RDRP, sbpa(1), RDRP], calls) == (1, 0)


@pytest.mark.parametrize("history,what", [
    ([sbpa(5805), sbpa(5809)], "returned normally"),                      # RDRP lost
    ([sbpa(5805), RDRP, RDRP, sbpa(5809)], None),                         # consistent
    ([sbpa(5805), sbpa(5807), sbpa(5809)], "returned normally"),        # RDRP lost
    ([sbpa(5805), RDRP, sbpa(5809), sbpa(5809)], "nobody sent"),          # run twice
    ([sbpa(5805), RDRP, sbpa(5809), sbpa(5807)], "nobody sent"),          # late: out of order
    ([sbpa(5805), sbpa(5807), sbpa(5807), RDRP, sbpa(5809)], "returned normally"),  # failed, twice
    ([sbpa(5805), RDRP, sbpa(5809), RDRP], "nobody sent"),                # a stray command
])
def test_violations_are_caught(history, what):
    calls = [(sbpa(5805), True), (RDRP, False), (sbpa(5807), False), (RDRP, True),
             (sbpa(5809), True)]
    if what is None:  # both RDRP ran, SBPA 5807 did not
        assert check_record(history, calls) == (1, 1)
        return
    with pytest.raises(AssertionError, match=what):
        check_record(history, calls)


def test_many_indistinguishable_failed_calls():
    """A run of failed RDRP between two certain ones: any number of them may have run, in any
    of the positions; exactly the right totals pass (a long run stays fast)."""
    calls = [(RDRP, True)] + [(RDRP, False)] * 200 + [(RDRP, True)]
    for k in (0, 1, 150, 200):
        assert check_record([RDRP] * (2 + k), calls) == (k, 200 - k)
    with pytest.raises(AssertionError):
        check_record([RDRP] * 203, calls)
    with pytest.raises(AssertionError):
        check_record([RDRP], calls)
