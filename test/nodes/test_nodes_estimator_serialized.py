"""The estimator's serialized fast path: the bytes it publishes deserialize (with rclpy's own
serializer) to exactly the messages the slow path would build, and the tactile decoder reads
what rclpy serialized, refusing frames that do not match the hand without losing its layout."""
import numpy as np
import pytest
from geometry_msgs.msg import WrenchStamped
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from rclpy.serialization import deserialize_message, serialize_message
from tacforce_msgs.msg import ForceEstimate, ForceEstimateArray

from tacforce_ros.hand.description import load_hand
from tacforce_ros.nodes.messages import stamp, tactile_hand, vector3, wrench_stamped
from tacforce_ros.nodes.serialized import (TactileHandDecoder, serialized_estimates,
                                           serialized_wrenches)

HAND = load_hand()
NAMES = [a.name for a in HAND.arrays]
FRAMES = [a.frame_id for a in HAND.arrays]
N = len(HAND.arrays)
STAMPS = st.integers(min_value=0, max_value=2**31 * 10**9 - 1)
FORCES = arrays(np.float64, (N, 3), elements=st.floats(-1e6, 1e6, allow_nan=False))


def estimate_array(ns, kinds, statuses, force, valid, ood):
    msg = ForceEstimateArray()
    msg.header.stamp, msg.header.frame_id = stamp(ns), HAND.base_frame
    for k in range(N):
        item = ForceEstimate(name=NAMES[k], model_kind=kinds[k], force=vector3(force[k]),
                             valid=bool(valid[k]), status=statuses[k],
                             ood_score=float(np.float32(ood[k])))
        item.header.stamp, item.header.frame_id = stamp(ns), FRAMES[k]
        msg.estimates.append(item)
    return msg


@given(ns=STAMPS, force=FORCES)
@settings(max_examples=30, deadline=None)
def test_wrenches_deserialize_to_the_messages_rclpy_would_send(ns, force):
    layout = serialized_wrenches(FRAMES)
    layout.set_stamp(ns)
    layout.set('force', force)
    for k in range(N):
        expected = wrench_stamped(ns, FRAMES[k], force[k])
        raw = layout.message(k)
        assert len(raw) == len(serialize_message(expected))
        assert deserialize_message(raw, WrenchStamped) == expected


@given(ns=STAMPS, force=FORCES, valid=arrays(np.bool_, N),
       ood=arrays(np.float32, N, elements=st.floats(0, 1e6, width=32)),
       statuses=st.lists(st.sampled_from(['ok', 'stale', 'input contains NaN or Inf', '']),
                         min_size=N, max_size=N))
@settings(max_examples=30, deadline=None)
def test_estimate_arrays_deserialize_to_the_same_message(ns, force, valid, ood, statuses):
    kinds = ['M3-lambda', 'M4', 'M5'] * (N // 3)
    layout = serialized_estimates(HAND.base_frame, NAMES, FRAMES, kinds, statuses)
    layout.set_stamp(ns)
    layout.set('force', force)
    layout.set('valid', valid)
    layout.set('ood_score', ood)
    expected = estimate_array(ns, kinds, statuses, force, valid, ood)
    raw = layout.message(0)
    assert len(raw) == len(serialize_message(expected))
    assert deserialize_message(raw, ForceEstimateArray) == expected


def test_a_scalar_fills_every_slot():
    layout = serialized_estimates(HAND.base_frame, NAMES, FRAMES, ['M3'] * N, ['stale'] * N)
    layout.set_stamp(5)
    layout.set('force', np.zeros((N, 3)))
    layout.set('valid', np.zeros(N, bool))
    layout.set('ood_score', np.inf)
    msg = deserialize_message(layout.message(0), ForceEstimateArray)
    assert all(e.ood_score == np.inf and not e.valid and e.status == 'stale'
               for e in msg.estimates)


@given(counts=arrays(np.uint16, (HAND.n_taxels, 3)), ns=STAMPS,
       temperatures=st.booleans())
@settings(max_examples=30, deadline=None)
def test_decoder_reads_what_rclpy_serialized(counts, ns, temperatures):
    decoder = TactileHandDecoder(HAND)
    temps = np.linspace(290.0, 310.0, HAND.n_taxels) if temperatures else None
    for frame in (counts, counts[::-1]):     # the second frame takes the learnt layout
        got_ns, got = decoder.decode(serialize_message(
            tactile_hand(ns, HAND, frame, temps, 1.5, 3)))
        assert got_ns == ns
        np.testing.assert_array_equal(got, frame)


def test_decoder_refuses_mismatched_frames_and_keeps_its_layout():
    decoder = TactileHandDecoder(HAND)
    counts = np.arange(HAND.n_taxels * 3, dtype=np.uint16).reshape(-1, 3)
    good = tactile_hand(0, HAND, counts, None, 0.0, 1)
    decoder.decode(serialize_message(good))

    short = tactile_hand(0, HAND, counts, None, 0.0, 1)
    short.arrays[3].z = short.arrays[3].z[:-1]
    with pytest.raises(ValueError, match=rf'{NAMES[3]}: \[\d+, \d+, \d+\] values'):
        decoder.decode(serialize_message(short))

    renamed = tactile_hand(0, HAND, counts, None, 0.0, 1)
    renamed.arrays[7].name = NAMES[7][:-1] + 'X'       # same length: same layout otherwise
    with pytest.raises(ValueError, match=f"where the hand has '{NAMES[7]}'"):
        decoder.decode(serialize_message(renamed))

    raw = serialize_message(good)
    with pytest.raises(ValueError, match='truncated'):
        decoder.decode(raw[:len(raw) // 2])
    with pytest.raises(ValueError, match='layout ends'):
        decoder.decode(raw + bytes(8))
    with pytest.raises(ValueError, match='little-endian'):
        decoder.decode(b'\x00\x00' + raw[2:])
    # the refusals did not spoil the learnt layout
    np.testing.assert_array_equal(decoder.decode(raw)[1], counts)
