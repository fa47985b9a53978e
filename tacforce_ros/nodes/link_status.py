"""Link-status reporting of the driver nodes: a periodic log line (and optional ~/status JSON)
of a driver's LinkDiagnostics counters (diagnostic_msgs is not installed everywhere), and the
driver's events (faults, recoveries) as log lines of the node at their level."""
from __future__ import annotations

import json
import logging
from collections.abc import Callable

from rclpy.clock import Clock, ClockType
from std_msgs.msg import String

from tacforce_ros.devices.polling import PollingDriver
from tacforce_ros.nodes.common import RELIABLE_QOS, ParamSpec, TacforceNode

# Parameters every driver node with a link-status report declares.
STATUS_PARAMETERS = (
    ParamSpec('diagnostics_period', 5.0, 'link counters to the log every this many wall '
              'seconds; 0 = never', range=(0.0, 3600.0)),
    ParamSpec('publish_status', False, 'also publish the counters as JSON on ~/status'),
)


class LinkStatusReporter:
    """Periodic log line (and optional ~/status JSON) of a driver's LinkDiagnostics counters.

    Wall time on purpose: link health is about the device, not about simulated time.
    """

    def __init__(self, node: TacforceNode, driver: PollingDriver,
                 node_counters: Callable[[], dict[str, int]] = dict) -> None:
        self.node = node
        self.node_counters = node_counters      # the node's own counters, reported alongside
        self.watch(driver)
        self.publisher = (node.create_publisher(String, '~/status', RELIABLE_QOS)
                          if node.params['publish_status'] else None)
        period = node.params['diagnostics_period']
        if period > 0:
            node.create_timer(period, self.report, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def watch(self, driver: PollingDriver) -> None:
        """Report on `driver` from now on (a node that replaced its driver calls this again)."""
        self.driver = driver
        driver.add_event_callback(self._log_event)

    def _log_event(self, level: int, message: str) -> None:
        # One call per severity: rclpy refuses a call site that changes its severity.
        logger = self.node.get_logger()
        if level >= logging.ERROR:
            logger.error(message)
        elif level >= logging.WARNING:
            logger.warning(message)
        else:
            logger.info(message)

    def report(self) -> None:
        counters = self.driver.diagnostics.as_dict()
        # samples not published: the node clock had not moved since the previous one (sim time)
        counters['same_stamp'] = sum(self.node.same_stamp.values())
        counters.update(self.node_counters())
        self.node.get_logger().info(
            ' '.join(f'{k}={v:.3f}' if isinstance(v, float) else f'{k}={v}'
                     for k, v in counters.items() if v not in ('', 0)))
        if self.publisher is not None:
            self.publisher.publish(String(data=json.dumps(counters)))
