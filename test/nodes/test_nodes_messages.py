"""numpy <-> ROS message conversion: whole-hand frames round-trip exactly, mismatches are named,
and the joint velocity filter follows a ramp and ignores repeated stamps."""
import numpy as np
import pytest
from rclpy.serialization import serialize_message
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from tacforce_ros.hand.description import load_hand
from tacforce_ros.nodes.allegro_driver import JointVelocity
from tacforce_ros.nodes.messages import (flat_counts, stamp, stamp_ns, tactile_hand,
                                         wrench_stamped)
from tacforce_ros.nodes.serialized import TactileHandDecoder, header_stamp_ns

HAND = load_hand()


@given(counts=arrays(np.uint16, (HAND.n_taxels, 3)),
       ns=st.integers(min_value=0, max_value=(2**31 - 1) * 10**9 + 999_999_999))
def test_tactile_hand_round_trips(counts, ns):
    msg = tactile_hand(ns, HAND, counts, None, 12.5, 2**32 + 7)
    assert stamp_ns(msg.header.stamp) == ns and msg.server_sequence == 7
    assert [a.header.frame_id for a in msg.arrays] == [a.frame_id for a in HAND.arrays]
    np.testing.assert_array_equal(flat_counts(msg, HAND), counts)
    ns_read, read = TactileHandDecoder(HAND).decode(serialize_message(msg))
    assert ns_read == ns
    np.testing.assert_array_equal(read, counts)


def test_mismatched_frames_are_named():
    msg = tactile_hand(0, HAND, np.zeros((HAND.n_taxels, 3), np.uint16), None, 0.0, 1)
    msg.arrays[3].x = msg.arrays[3].x[:-1]
    with pytest.raises(ValueError, match=HAND.arrays[3].name):
        flat_counts(msg, HAND)
    msg.arrays = msg.arrays[:5]
    with pytest.raises(ValueError, match='5 arrays'):
        flat_counts(msg, HAND)


def test_stamp_round_trip():
    assert stamp_ns(stamp(1_234_567_890_123)) == 1_234_567_890_123


def test_joint_velocity_follows_a_ramp_and_skips_repeated_stamps():
    velocity = JointVelocity(cutoff_hz=30.0)
    rate = np.linspace(-1.0, 1.0, 16)        # rad/s
    for k in range(200):                     # 0.6 s at 333 Hz: many filter time constants
        t_ns = k * 3_000_000
        velocity.update(rate * t_ns * 1e-9, t_ns)
        before = velocity.qdot.copy()
        velocity.update(rate * t_ns * 1e-9 + 0.5, t_ns)    # same stamp: ignored
        np.testing.assert_array_equal(velocity.qdot, before)
    np.testing.assert_allclose(velocity.qdot, rate, atol=1e-6)


@given(ns=st.integers(min_value=0, max_value=2**31 * 10**9 - 1), frame=st.text(max_size=20))
def test_header_stamp_read_from_serialized_messages(ns, frame):
    """sim_world's lockstep reads only the stamp of the messages it waits for."""
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState
    from tacforce_msgs.msg import CalibrationSample, ControllerState
    for message in (wrench_stamped(ns, frame, [1.0, 2.0, 3.0]), ControllerState(finger=frame),
                    CalibrationSample(), JointState(name=[frame])):
        message.header.stamp = stamp(ns)
        assert header_stamp_ns(serialize_message(message)) == ns


def test_header_stamp_of_something_else_is_refused():
    with pytest.raises(ValueError, match='CDR'):
        header_stamp_ns(b'\x00\x00\x00\x00' + bytes(8))      # big-endian encapsulation
    with pytest.raises(ValueError, match='CDR'):
        header_stamp_ns(b'\x00\x01\x00\x00\x01')             # too short for a stamp


def test_a_stamp_beyond_the_time_message_is_refused_not_wrapped():
    with pytest.raises(ValueError, match='does not fit'):
        tactile_hand(2**31 * 10**9, HAND, np.zeros((HAND.n_taxels, 3), np.uint16), None, 0.0, 1)
