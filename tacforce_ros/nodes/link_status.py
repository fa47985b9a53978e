"""Link health of the driver nodes on /diagnostics (diagnostic_msgs/DiagnosticArray), as
diagnostic_updater publishes it: one DiagnosticStatus per driver every `diagnostics_period` wall
seconds while the driver is active (a managed driver that is deactivated says so once, STALE,
and reports again when activated), named '<node's full name>: device link' (e.g.
'/left/xela_driver: device link'), with the device as hardware_id, a level
(devices/diagnostics.link_health: OK, WARN, ERROR, STALE), and the link's counters as values
(never reset: a driver that replaces its client carries the old one's counts), the delivery rate
over the period, and the last error while the link is not OK. rqt_robot_monitor and Foxglove's
diagnostics panel read it. A change of level is logged once at its severity with the counters,
and the driver's own events (faults, recoveries) are logged as they happen."""
from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType

from tacforce_ros.devices.diagnostics import (ERROR, LEVEL_NAMES, OK, STALE, WARN,
                                              LinkDiagnostics, link_health)
from tacforce_ros.devices.polling import PollingDriver
from tacforce_ros.nodes.node_base import TacforceNode
from tacforce_ros.nodes.parameters import ParamSpec
from tacforce_ros.nodes.qos import publisher_qos
from tacforce_ros.topics import TOPIC_DIAGNOSTICS

# Parameters every driver node with a link-health report declares.
STATUS_PARAMETERS = (
    ParamSpec('diagnostics_period', 1.0, 'link health on /diagnostics every this many wall '
              'seconds (diagnostic_updater\'s default rate); 0 = never', range=(0.0, 3600.0)),
)
# The log severity of each health level.
_LOG_LEVEL = {OK: logging.INFO, WARN: logging.WARNING, STALE: logging.WARNING,
              ERROR: logging.ERROR}
# LinkDiagnostics fields that count (summed over the clients a driver had).
_COUNTERS = tuple(f.name for f in dataclasses.fields(LinkDiagnostics)
                  if f.type in ('int', int) and not f.name.startswith('_'))


class LinkStatusReporter:
    """Publishes a driver's link health on /diagnostics; logs its changes of level.

    Wall time on purpose: link health is about the device, not about simulated time.
    `failure()` says what the node knows to be wrong beyond the counters ('' when nothing);
    a lost link (the driver's fatal_error) always counts.
    """

    def __init__(self, node: TacforceNode, driver: PollingDriver, hardware_id: str,
                 node_counters: Callable[[], dict[str, int]] = dict,
                 failure: Callable[[], str] = lambda: '') -> None:
        self.node = node
        self.hardware_id = hardware_id
        self.node_counters = node_counters      # the node's own counters, reported alongside
        self.failure = failure
        # The node's full name: /diagnostics is one topic for every namespace.
        self.name = f'{node.get_fully_qualified_name()}: device link'
        self._carried = dict.fromkeys(_COUNTERS, 0)
        self._carried_seen = math.nan
        self.driver: PollingDriver | None = None
        self._before: LinkDiagnostics | None = None
        self._before_time = time.monotonic()
        self.level: int | None = None
        self.watch(driver)
        self.publisher = node.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS,
                                               publisher_qos(TOPIC_DIAGNOSTICS))
        period = node.params['diagnostics_period']
        self.timer = (node.create_timer(period, self.report,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))
                      if period > 0 else None)
        if self.timer is not None:
            self.timer.cancel()     # reports start with resume() (create_timer's autostart
            #                         argument is not in Humble)

    def watch(self, driver: PollingDriver, hardware_id: str | None = None) -> None:
        """Report on `driver` from now on (a node that replaced its driver calls this again);
        the counts of the one before are carried on."""
        if self.driver is not None:
            old = self.counters()
            self._carried = {name: getattr(old, name) for name in _COUNTERS}
            self._carried_seen = old.last_seen
        self.driver = driver
        self.hardware_id = hardware_id or self.hardware_id
        driver.add_event_callback(self._log_event)

    def resume(self) -> None:
        """Report every period from now on (the driver was activated)."""
        # The first period starts now: what rose while inactive is not this period's trouble.
        self._before, self._before_time, self.level = self.counters(), time.monotonic(), None
        if self.timer is not None:
            self.timer.reset()

    def pause(self, message: str) -> None:
        """Stop reporting (the driver was deactivated), saying why once, at level STALE."""
        if self.timer is None:
            return                  # diagnostics_period 0: never reported
        self.timer.cancel()
        self._publish(STALE, message, {name: getattr(self.counters(), name)
                                       for name in _COUNTERS})
        self.level = STALE

    def counters(self) -> LinkDiagnostics:
        """The link's counters since the node started, over every client it had."""
        snap = self.driver.diagnostics.snapshot()
        for name, carried in self._carried.items():
            setattr(snap, name, getattr(snap, name) + carried)
        if math.isnan(snap.last_seen):
            snap.last_seen = self._carried_seen
        return snap

    def _log_event(self, level: int, message: str) -> None:
        # One call per severity: rclpy refuses a call site that changes its severity.
        logger = self.node.get_logger()
        if level >= logging.ERROR:
            logger.error(message)
        elif level >= logging.WARNING:
            logger.warning(message)
        else:
            logger.info(message)

    def _failure(self) -> str:
        fatal = self.driver.fatal_error
        return f'link lost: {fatal}' if fatal is not None else self.failure()

    def report(self) -> None:
        """Publish the link's health over the period since the previous report."""
        snap, now = self.counters(), time.monotonic()
        level, message = link_health(snap, self._before, self._failure())
        values: dict[str, object] = {name: getattr(snap, name) for name in _COUNTERS}
        # samples not published: the node clock had not moved since the previous one (sim time)
        values['same_stamp'] = sum(self.node.same_stamp.values())
        values.update(self.node_counters())
        values['age_s'] = round(snap.age(), 3)
        if self._before is not None and now > self._before_time:
            values['rate_hz'] = round((snap.delivered - self._before.delivered)
                                      / (now - self._before_time), 1)
        if level != OK and snap.last_error:
            values['last_error'] = snap.last_error
        self._before, self._before_time = snap, now
        self._publish(level, message, values)
        if level != self.level:
            self.level = level
            self._log_event(_LOG_LEVEL[level], f'link {LEVEL_NAMES[level]}: {message}; ' + ' '.join(
                f'{k}={v}' for k, v in values.items() if v not in ('', 0)))

    def _publish(self, level: int, message: str, values: dict[str, object]) -> None:
        status = DiagnosticStatus(level=bytes([level]), name=self.name, message=message,
                                  hardware_id=self.hardware_id,
                                  values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.node.get_clock().now().to_msg()
        self.publisher.publish(array)

    def log_counters(self) -> None:
        """When the link closes: the counters to the log whatever the level."""
        snap = self.counters()
        self.node.get_logger().info('link counters at close: ' + ' '.join(
            f'{name}={getattr(snap, name)}' for name in _COUNTERS if getattr(snap, name)))
