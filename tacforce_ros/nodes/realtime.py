"""Real-time scheduling for the nodes on the 100 Hz path (estimator, force_controller,
allegro_driver): with `realtime_priority` above 0 every thread of the process (rclpy's and the
DDS layer's) runs SCHED_FIFO at that priority, as ros2_control's real-time threads do, so a frame
is not kept waiting behind ordinary processes; without the right (CAP_SYS_NICE or an rtprio
limit) the node says so and runs normally. 0 (the default) leaves the normal scheduler."""
from __future__ import annotations

import os

from tacforce_ros.nodes.parameters import ParamSpec

REALTIME_PRIORITY = ParamSpec(
    'realtime_priority', 0, 'SCHED_FIFO priority (1-98) of all of this process\'s threads; '
    '0 = the normal scheduler. Needs CAP_SYS_NICE or an rtprio limit, else a warning',
    range=(0, 98))


def use_realtime_scheduling(priority: int) -> None:
    """SCHED_FIFO at `priority` for every thread of this process (threads started later by them
    inherit it); 0 returns them to the normal scheduler. OSError when the system refuses (no
    right, or not Linux)."""
    if not hasattr(os, 'sched_setscheduler'):
        raise OSError('SCHED_FIFO needs Linux')
    policy = os.SCHED_FIFO if priority > 0 else os.SCHED_OTHER
    param = os.sched_param(priority)
    for tid in os.listdir('/proc/self/task'):
        try:
            os.sched_setscheduler(int(tid), policy, param)
        except ProcessLookupError:   # a thread that ended meanwhile
            continue
