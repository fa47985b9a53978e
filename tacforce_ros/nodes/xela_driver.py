"""xela_driver: xela_server (XELA uSkin) -> /tactile/raw (tacforce_msgs/TactileHand).

Every server frame (100 Hz) becomes one whole-hand message stamped with the server's time of
the frame (devices/device_clock.py), so stamps keep the frames' spacing whatever the WebSocket
and the host's scheduling add: as it is with `server_clock` = node (xela_server on this host, on
its system time, which is ROS time; or the simulator's xela_server emulator, on simulated time),
mapped onto the node clock by the minimum-delay offset with `server_clock` = own (a server on
another computer, its clock within `max_clock_skew` of this one's rate). A frame whose server
time repeats the previous one's is the same reading and is not published (counted as same_stamp
in the link report); under use_sim_time, frames that arrive before the first /clock are dropped
and counted. Each TactileArray carries its array frame {S0} as frame_id (after `frame_prefix`).
Frames of a sensor other than the hand description's (the server's model string: XR23AHRCPP is
the right hand, XR23AHLCPP the left) are dropped, counted and reported: their taxel order is not
the description's. The client reconnects on its own; malformed frames are counted and dropped.
The link's health goes to /diagnostics every `diagnostics_period` s (wall time;
nodes/link_status.py).
A managed (lifecycle) node (nodes/managed_driver.py): configure connects to xela_server, activate
publishes, deactivate stops publishing (the connection stays), cleanup disconnects.
"""
from __future__ import annotations

import sys

from tacforce_msgs.msg import TactileHand

from tacforce_ros.devices.device_clock import DEFAULT_MAX_SKEW, DeviceClock
from tacforce_ros.devices.xela import XelaClient, XelaConfig, XelaFrame
from tacforce_ros.nodes.parameters import (FRAME_PREFIX, HAND_CONFIG, ParamSpec, ParameterError,
                                           hand_parameter)
from tacforce_ros.nodes.qos import publisher_qos
from tacforce_ros.nodes.runner import run_node
from tacforce_ros.nodes.link_status import STATUS_PARAMETERS
from tacforce_ros.nodes.managed_driver import AUTOSTART, ManagedDriver
from tacforce_ros.nodes.messages import tactile_hand
from tacforce_ros.topics import TOPIC_TACTILE, relative

# Frames are stamped within milliseconds of their arrival; a second apart means two clocks.
CLOCK_MISMATCH_NS = 1_000_000_000


class XelaDriver(ManagedDriver):
    """Publishes XELA uSkin whole-hand frames from xela_server on /tactile/raw."""

    NODE_NAME = 'xela_driver'
    PARAMETERS = (
        ParamSpec('url', 'ws://127.0.0.1:5000', 'xela_server WebSocket URL'),
        ParamSpec('sensor_key', '1', 'key of the hand sensor in the server frames'),
        ParamSpec('stale_after', 0.05, 'link counted stale after this long without frames (s)',
                  range=(0.005, 10.0)),
        ParamSpec('reconnect_max', 2.0, 'longest wait between reconnect attempts (s)',
                  range=(0.01, 60.0)),
        HAND_CONFIG, FRAME_PREFIX,
        ParamSpec('server_clock', 'node', 'node: the server\'s frame times are on the node '
                  'clock (server on this host, or the simulator\'s); own: a clock of its own, '
                  'mapped', choices=('node', 'own')),
        ParamSpec('max_clock_skew', DEFAULT_MAX_SKEW, 'server_clock own: largest rate '
                  'difference between the server\'s clock and the node clock (s/s)',
                  range=(0.0, 0.009)),
    ) + STATUS_PARAMETERS + (AUTOSTART,)

    def __init__(self, **node_options) -> None:
        super().__init__(**node_options)
        p = self.params
        if not p['url'].startswith(('ws://', 'wss://')):
            raise ParameterError(f'url: {p["url"]!r} is not a ws:// or wss:// URL')
        self.hand = hand_parameter(p)
        self.publisher = self.create_lifecycle_publisher(TactileHand, relative(TOPIC_TACTILE),
                                                         publisher_qos(TOPIC_TACTILE))
        self.device_clock = DeviceClock(p['server_clock'] == 'node', p['max_clock_skew'])
        self.client: XelaClient | None = None
        self.wrong_sensor = ''           # the model the server reports, when not the hand's
        self.wrong_sensor_frames = 0

    def open_device(self) -> None:
        p = self.params
        self.client = XelaClient(XelaConfig(url=p['url'], sensor_key=p['sensor_key'],
                                            n_taxels=self.hand.n_taxels,
                                            stale_after=p['stale_after'],
                                            reconnect_max=p['reconnect_max']))
        self.client.add_callback(self._publish)
        self.report_link(self.client, f'xela_server {p["url"]}', node_counters=lambda: {
            'clock_resets': self.device_clock.counts.resets,
            'stamps_moved': self.device_clock.counts.moved,
            'wrong_sensor_frames': self.wrong_sensor_frames},
            failure=lambda: (f'the server reports sensor {self.wrong_sensor}, hand_config is '
                             f'{self.hand.sensor_model}: nothing published'
                             if self.wrong_sensor else ''))
        self.client.start()     # connects, and reconnects on its own
        self.get_logger().info(f'reading {p["url"]} ({self.hand.n_taxels} taxels, '
                               f'{len(self.hand.arrays)} arrays) -> '
                               f'{self.topic_name(TOPIC_TACTILE)} while active')

    def close_device(self) -> None:
        if self.client is not None:
            self.client.close()

    def _publish(self, frame: XelaFrame) -> None:
        # Called from the client's thread; rclpy publishers are thread-safe.
        if not self.active:
            return
        if frame.model and self.hand.sensor_model and frame.model != self.hand.sensor_model:
            # The other hand's taxel order (or another sensor): its frames would put every
            # reading on the wrong taxel, so none is published.
            self.wrong_sensor = frame.model
            self.wrong_sensor_frames += 1
            self.get_logger().error(
                f'xela_server reports sensor {frame.model}, but hand_config describes '
                f'{self.hand.sensor_model} (the {self.hand.side} hand): frames dropped',
                throttle_duration_sec=5.0)
            return
        self.wrong_sensor = ''
        now = self.stamp_ns()
        if now is None:
            return      # before the first /clock under use_sim_time: no valid stamp yet
        counts = self.device_clock.counts
        resets = counts.resets
        stamp = self.device_clock.stamp(round(frame.server_time * 1e9), now)
        if counts.resets > resets:
            self.get_logger().warning(f'xela_server time went back to {frame.server_time:.3f} s:'
                                      ' mapping frame times onto the clock again')
        if stamp is None:
            self.same_stamp[TOPIC_TACTILE] = counts.repeated
            return
        if abs(stamp - now) > CLOCK_MISMATCH_NS:
            self.get_logger().warning(
                f'xela_server frame time {frame.server_time:.3f} s is {(stamp - now) * 1e-9:+.1f}'
                ' s off the node clock: a server with a clock of its own needs server_clock:=own',
                throttle_duration_sec=10.0)
        self.publisher.publish(tactile_hand(stamp, self.hand, frame.counts, frame.temperatures,
                                            frame.server_time, frame.sequence,
                                            self.params[FRAME_PREFIX.name]))


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(XelaDriver, args))


if __name__ == '__main__':
    main()
