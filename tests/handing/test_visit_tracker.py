"""The visit tracker: noise holds a visit open, a rise waits for confirmation, noise does not
reset the count and another id does."""

import pytest

from pcvfe_drake.handing.visit_tracker import NOISE, VisitTracker


def test_confirmation_counts_from_the_first_frame_and_noise_does_not_reset_it():
    visit = VisitTracker(noise_hold_s=1.0, confirm_s=1.0)
    visit.observe(0.0, 2)  # the first context: compared with the unknown value
    assert visit.pending(2) and visit.confirmed == NOISE
    visit.observe(0.9, 2)
    assert visit.pending(2)
    visit.observe(1.0, 2)
    assert not visit.pending(2) and visit.confirmed == 2
    visit.observe(1.1, 1)  # a switch to context 1
    assert visit.pending(1) and visit.confirmed == 2
    visit.observe(1.5, NOISE)  # noise in between: the visit of 1 held
    assert visit.in_noise and visit.visit() == 1 and visit.pending(1)
    visit.observe(2.1, 1)  # 1 s after 1's first frame: confirmed
    assert not visit.pending(1) and visit.confirmed == 1
    # another context's id restarts the count
    visit.observe(2.2, 3)
    visit.observe(2.7, 4)
    visit.observe(3.6, 4)
    assert visit.pending(4) and visit.confirmed == 1
    visit.observe(3.7, 4)
    assert visit.confirmed == 4
    # noise beyond the hold ends the visit: the unknown value is what a later rise is
    # compared with
    visit.observe(4.0, NOISE)
    assert visit.visit() == 4
    visit.observe(4.71, NOISE)
    assert visit.visit() == NOISE and visit.confirmed == NOISE
    # off: never pending
    assert not VisitTracker(confirm_s=0.0).pending(5)


@pytest.mark.parametrize("hold_s", [0.0, 0.5])
def test_noise_hold_keeps_the_visit_for_its_length_only(hold_s):
    visit = VisitTracker(noise_hold_s=hold_s, confirm_s=0.0)
    visit.observe(0.0, 7)
    visit.observe(0.4, NOISE)
    assert visit.visit() == (7 if hold_s >= 0.4 else NOISE)
    visit.observe(0.6, NOISE)
    assert visit.visit() == NOISE
    visit.observe(0.7, 7)  # its id back: visited again
    assert visit.visit() == 7 and not visit.in_noise
