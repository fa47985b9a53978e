"""A force sequence cut short plays the same commands up to the cut."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tacforce_ros.control.command_sequence import ForceSequence, SequenceError

PAPER = ForceSequence.load('paper_70s')


@settings(max_examples=60, deadline=None)
@given(cut=st.floats(0.01, 80.0), fraction=st.floats(0.0, 1.0))
def test_a_cut_sequence_plays_the_same_commands_until_the_cut(cut, fraction):
    short = PAPER.until(cut)
    assert short.duration == pytest.approx(min(cut, PAPER.duration))
    t = fraction * short.duration
    np.testing.assert_allclose(short.force_at(t), PAPER.force_at(t), atol=1e-12)
    np.testing.assert_allclose(short.force_at(short.duration + 1.0),
                               PAPER.force_at(short.duration - 1e-9), atol=1e-6)


def test_a_cut_on_a_segment_boundary_ends_on_that_segment_and_a_bad_cut_is_refused():
    short = PAPER.until(16.0)          # the 15-16 s ramp to 1 N ends here
    np.testing.assert_allclose(short.end[-1], [0.0, 0.0, -1.0])
    with pytest.raises(SequenceError):
        PAPER.until(0.0)
