"""xela_driver: xela_server (XELA uSkin) -> /tactile/raw (tacforce_msgs/TactileHand).

Every server frame (100 Hz) becomes one whole-hand message stamped on arrival with the node
clock (sim time under use_sim_time: frames that arrive before the first /clock are dropped and
counted, never stamped 0); each TactileArray carries its array frame {S0} as frame_id.
The client reconnects on its own; malformed frames are counted and dropped. Every
`diagnostics_period` s (wall time) the link counters go to the log and, if `publish_status`,
as JSON on ~/status (std_msgs/String: diagnostic_msgs is not available everywhere).
"""
from __future__ import annotations

import sys

from tacforce_msgs.msg import TactileHand

from tacforce_ros.devices.xela import XelaClient, XelaConfig, XelaFrame
from tacforce_ros.hand.description import HandConfigError, load_hand
from tacforce_ros.nodes.common import (ParameterError, ParamSpec, TacforceNode, publisher_qos,
                                       run_node)
from tacforce_ros.nodes.link_status import STATUS_PARAMETERS, LinkStatusReporter
from tacforce_ros.nodes.messages import tactile_hand
from tacforce_ros.topics import TOPIC_TACTILE

class XelaDriver(TacforceNode):
    """Publishes XELA uSkin whole-hand frames from xela_server on /tactile/raw."""

    NODE_NAME = 'xela_driver'
    PARAMETERS = (
        ParamSpec('url', 'ws://127.0.0.1:5000', 'xela_server WebSocket URL'),
        ParamSpec('sensor_key', '1', 'key of the hand sensor in the server frames'),
        ParamSpec('stale_after', 0.05, 'link counted stale after this long without frames (s)',
                  range=(0.005, 10.0)),
        ParamSpec('reconnect_max', 2.0, 'longest wait between reconnect attempts (s)',
                  range=(0.01, 60.0)),
        ParamSpec('hand_config', '', 'hand description YAML; empty = the default hand'),
    ) + STATUS_PARAMETERS

    def __init__(self) -> None:
        super().__init__()
        p = self.params
        if not p['url'].startswith(('ws://', 'wss://')):
            raise ParameterError(f'url: {p["url"]!r} is not a ws:// or wss:// URL')
        try:
            self.hand = load_hand(p['hand_config'] or None)
        except (HandConfigError, OSError) as exc:
            raise ParameterError(f'hand_config: {exc}') from None
        self.publisher = self.create_publisher(TactileHand, TOPIC_TACTILE,
                                               publisher_qos(TOPIC_TACTILE))
        self.client = XelaClient(XelaConfig(url=p['url'], sensor_key=p['sensor_key'],
                                            n_taxels=self.hand.n_taxels,
                                            stale_after=p['stale_after'],
                                            reconnect_max=p['reconnect_max']))
        self.client.add_callback(self._publish)
        self.status = LinkStatusReporter(self, self.client)
        self.client.start()
        self.get_logger().info(f'reading {p["url"]} ({self.hand.n_taxels} taxels, '
                               f'{len(self.hand.arrays)} arrays) -> {TOPIC_TACTILE}')

    def _publish(self, frame: XelaFrame) -> None:
        # Called from the client's thread; rclpy publishers are thread-safe.
        now = self.stamp_ns()
        if now is None:
            return      # before the first /clock under use_sim_time: no valid stamp yet
        self.publisher.publish(tactile_hand(now, self.hand, frame.counts, frame.temperatures,
                                            frame.server_time, frame.sequence))

    def on_shutdown(self) -> None:
        self.client.close()
        self.status.report()


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(XelaDriver, args))


if __name__ == '__main__':
    main()
