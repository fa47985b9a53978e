"""QoS per topic: one table, `TOPIC_QOS` in tacforce_ros/topics.py, decides; publisher_qos() and
subscriber_qos() read it.

* high-rate sensor streams (/tactile/raw, /ft_sensor/wrench, /joint_states, estimates):
  publishers RELIABLE keep-last, subscribers best-effort sensor-data QoS, as REP 2003 advises:
  a reliable publisher matches both kinds of subscriber, and a best-effort subscriber never
  stalls the publisher nor gets an old sample retransmitted after a newer one;
* commands and controller state (/force_controller/desired, /force_controller/state):
  reliable both ways, keep-last 10, volatile: a dropped set-point is a real loss, and late
  joiners must not act on stale commands;
* the recorder's synchronised samples (/calibration/sample): reliable both ways, transient-local,
  keep-last KEPT_DEPTH: a late joiner (the operator's coverage view) gets the session's samples
  from before it matched. A volatile subscriber still matches, and gets only what follows.
"""
from __future__ import annotations

from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy,
                       qos_profile_sensor_data)

from tacforce_ros.topics import KEPT, KEPT_DEPTH, PUBLISHER_DEPTH, SENSOR, qos_kind

SENSOR_PUBLISHER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=PUBLISHER_DEPTH,
                                  reliability=ReliabilityPolicy.RELIABLE,
                                  durability=DurabilityPolicy.VOLATILE)
SENSOR_SUBSCRIBER_QOS = qos_profile_sensor_data
RELIABLE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=PUBLISHER_DEPTH,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)
KEPT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=KEPT_DEPTH,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def publisher_qos(topic: str) -> QoSProfile:
    kind = qos_kind(topic)
    return SENSOR_PUBLISHER_QOS if kind == SENSOR else KEPT_QOS if kind == KEPT else RELIABLE_QOS


def subscriber_qos(topic: str, depth: int | None = None) -> QoSProfile:
    """Subscriber QoS of `topic`; `depth` sets the history, keeping the reliability policy:
    deeper for a consumer that must ride out CPU hiccups without losing samples (a recorder),
    1 for one that acts on the newest sample only (a controller: rclpy takes a queue's oldest
    message first, one per executor pass, so a history of several feeds it old states)."""
    kind = qos_kind(topic)
    base = (SENSOR_SUBSCRIBER_QOS if kind == SENSOR else KEPT_QOS if kind == KEPT
            else RELIABLE_QOS)
    if depth is None:
        return base
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=base.reliability, durability=base.durability)
