"""What the estimator's serialized fast path (nodes/serialized.py) saves per tactile frame.

Two halves of the estimator's frame, each timed both ways on the same data:
* intake: a serialized /tactile/raw frame -> (n_taxels, 3) counts, by rclpy's
  deserialize_message and the message object's fields (messages.flat_counts) against
  TactileHandDecoder's precomputed gather;
* output: 18 WrenchStamped and one ForceEstimateArray -> the bytes a publisher sends, by
  building message objects and rclpy's serialize_message (what publish() does with an object)
  against SerializedMessages' overwritten layouts.
The two ways alternate in blocks, so a busy machine slows both alike and the ratio holds.
"""
from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from rclpy.serialization import deserialize_message, serialize_message
from tacforce_msgs.msg import ForceEstimate, ForceEstimateArray, TactileHand

from tacforce_ros.hand.description import HandDescription
from tacforce_ros.nodes.messages import flat_counts, stamp, tactile_hand, vector3, wrench_stamped
from tacforce_ros.nodes.serialized import (TactileHandDecoder, serialized_estimates,
                                           serialized_wrenches)

BLOCK = 50      # frames per timed block; blocks of the two ways alternate


def _alternating(ways: dict[str, Callable[[int], object]], frames: int) -> dict[str, dict]:
    """Per-frame microseconds of each way: median and p99 over `frames` frames."""
    times = {name: [] for name in ways}
    for start in range(0, frames, BLOCK):
        for name, way in ways.items():
            for k in range(start, min(start + BLOCK, frames)):
                t0 = time.perf_counter_ns()
                way(k)
                times[name].append(time.perf_counter_ns() - t0)
    return {name: {'median_us': float(np.median(t)) / 1e3,
                   'p99_us': float(np.percentile(t, 99)) / 1e3} for name, t in times.items()}


def intake_cost(hand: HandDescription, frames: int, seed: int = 0) -> dict[str, dict]:
    rng = np.random.default_rng(seed)
    raws = [serialize_message(tactile_hand(k * 10_000_000, hand,
                                           rng.integers(0, 65535, (hand.n_taxels, 3), np.uint16),
                                           None, 0.01 * k, k))
            for k in range(min(frames, 100))]
    decoder = TactileHandDecoder(hand)
    return _alternating({
        'message objects': lambda k: flat_counts(deserialize_message(raws[k % len(raws)],
                                                                     TactileHand), hand),
        'serialized': lambda k: decoder.decode(raws[k % len(raws)]),
    }, frames)


def output_cost(hand: HandDescription, frames: int, seed: int = 0) -> dict[str, dict]:
    rng = np.random.default_rng(seed)
    names = [a.name for a in hand.arrays]
    frame_ids = [a.frame_id for a in hand.arrays]
    kinds = ['M3-lambda'] * len(names)
    forces = rng.normal(size=(100, len(names), 3))
    wrenches = serialized_wrenches(frame_ids)
    estimates = serialized_estimates(hand.base_frame, names, frame_ids, kinds, ['ok'] * len(names))

    def objects(k: int) -> list[bytes]:
        ns, force = k * 10_000_000, forces[k % len(forces)]
        out = [serialize_message(wrench_stamped(ns, frame_ids[i], force[i]))
               for i in range(len(names))]
        array = ForceEstimateArray()
        array.header.stamp, array.header.frame_id = stamp(ns), hand.base_frame
        for i in range(len(names)):
            item = ForceEstimate(name=names[i], model_kind=kinds[i], force=vector3(force[i]),
                                 valid=True, status='ok', ood_score=0.0)
            item.header.stamp, item.header.frame_id = stamp(ns), frame_ids[i]
            array.estimates.append(item)
        return out + [serialize_message(array)]

    def serialized(k: int) -> list[bytes]:
        ns, force = k * 10_000_000, forces[k % len(forces)]
        wrenches.set_stamp(ns)
        wrenches.set('force', force)
        out = [wrenches.message(i) for i in range(len(wrenches))]
        estimates.set_stamp(ns)
        estimates.set('force', force)
        estimates.set('valid', np.ones(len(names), bool))
        estimates.set('ood_score', np.zeros(len(names), np.float32))
        return out + [estimates.message(0)]

    return _alternating({'message objects': objects, 'serialized': serialized}, frames)
