"""ft_bridge: ATI Net F/T (RDT over UDP) -> /ft_sensor/wrench (geometry_msgs/WrenchStamped).

Each RDT record becomes one message in the sensor frame {F} (`frame_id`), N and N m, stamped on
arrival with the node clock (sim time under use_sim_time); a record arriving while that clock
has not moved since the previous one (sim time only) is the same instant and is not published
(counted, logged at shutdown). Out-of-order and malformed records are
counted and dropped by the client; so are records whose status word reports a fault (anything
but 0 or the monitor warning 0x80010000): they are withheld from the topic, and so never
recorded or paired, with an ERROR line when they start and an INFO line when the status clears.
~/bias (std_srvs/Trigger) zeroes the reading on the host with the mean of the last `bias_window`
records (the paper biases with nothing on the plate).
A managed (lifecycle) node (nodes/managed_driver.py): configure opens the UDP link and asks the
box to stream, activate publishes, deactivate stops publishing (the box streams on, so the bias
window stays current), cleanup asks the box to stop and closes the link.
"""
from __future__ import annotations

import sys

from geometry_msgs.msg import WrenchStamped
from rclpy.clock import Clock, ClockType
from std_srvs.srv import Trigger

from tacforce_ros.devices.netft import (FORCE_UNITS_SI, TORQUE_UNITS_SI, NetFtClient, NetFtConfig,
                                        WrenchSample)
from tacforce_ros.nodes.parameters import FRAME_PREFIX, ParamSpec, ParameterError
from tacforce_ros.nodes.qos import publisher_qos
from tacforce_ros.nodes.runner import run_node
from tacforce_ros.nodes.link_status import STATUS_PARAMETERS
from tacforce_ros.nodes.managed_driver import AUTOSTART, ManagedDriver
from tacforce_ros.nodes.messages import wrench_stamped
from tacforce_ros.topics import TOPIC_WRENCH, relative


class FtBridge(ManagedDriver):
    """Publishes the Net F/T wrench in the sensor frame; ~/bias zeroes it."""

    NODE_NAME = 'ft_bridge'
    PARAMETERS = (
        ParamSpec('host', '192.168.1.1', 'Net F/T box IP address (the box\'s default)'),
        ParamSpec('port', 49152, 'RDT UDP port', range=(1, 65535)),
        ParamSpec('frame_id', 'ft_sensor', 'sensor frame {F} (URDF)'), FRAME_PREFIX,
        ParamSpec('counts_per_force', 1_000_000.0, 'box setting cfgcpf', range=(1e-6, 1e12)),
        ParamSpec('counts_per_torque', 1_000_000.0, 'box setting cfgcpt', range=(1e-6, 1e12)),
        ParamSpec('force_unit', 'N', 'box setting scfgfu', choices=tuple(FORCE_UNITS_SI)),
        ParamSpec('torque_unit', 'N-m', 'box setting scfgtu', choices=tuple(TORQUE_UNITS_SI)),
        ParamSpec('bias_window', 100, 'records averaged by ~/bias', range=(1, 100000)),
        ParamSpec('stale_after', 0.05, 'link counted stale after this long without records (s)',
                  range=(0.001, 10.0)),
        ParamSpec('restart_after', 1.0, 'ask the box for a new stream after this long without '
                  'records (s, wall time)', range=(0.1, 60.0)),
    ) + STATUS_PARAMETERS + (AUTOSTART,)

    def __init__(self, **node_options) -> None:
        super().__init__(**node_options)
        p = self.params
        self.publisher = self.create_lifecycle_publisher(WrenchStamped, relative(TOPIC_WRENCH),
                                                         publisher_qos(TOPIC_WRENCH))
        self.config = NetFtConfig(
            host=p['host'], port=p['port'], counts_per_force=p['counts_per_force'],
            counts_per_torque=p['counts_per_torque'], force_unit=p['force_unit'],
            torque_unit=p['torque_unit'], stale_after=p['stale_after'],
            bias_window=p['bias_window'])
        self.client: NetFtClient | None = None
        self.restart_timer = None
        self.create_service(Trigger, '~/bias', self._on_bias)

    def open_device(self) -> None:
        p = self.params
        self.client = self._connect()
        self.report_link(self.client, f'Net F/T {p["host"]}:{p["port"]}')
        self.client.start()
        # RDT is request-driven: a box that rebooted (or came up after us) streams only when
        # asked again, so a silent link is re-requested (wall time: a device matter).
        self.restart_timer = self.create_timer(p['restart_after'], self._restart_if_silent,
                                               clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(f'reading udp {p["host"]}:{p["port"]} '
                               f'-> {self.topic_name(TOPIC_WRENCH)} '
                               f'in {self.frame(p["frame_id"])} while active')

    def close_device(self) -> None:
        if self.restart_timer is not None:
            self.destroy_timer(self.restart_timer)
            self.restart_timer = None
        if self.client is not None:
            self.client.close()

    def _connect(self) -> NetFtClient:
        try:
            client = NetFtClient(self.config)
        except OSError as exc:
            raise ParameterError(f'host/port: cannot reach {self.config.host}:'
                                 f'{self.config.port}: {exc}') from None
        client.add_callback(self._publish)
        return client

    def _restart_if_silent(self) -> None:
        if self.client.diagnostics.age() <= self.params['restart_after']:
            return
        self.get_logger().info(f'no records for {self.params["restart_after"]:g} s; asking '
                               'the box for a new stream', throttle_duration_sec=10.0)
        self.client.close()
        self.client = self._connect()
        self.status.watch(self.client)     # before it starts: its first events are logged too
        self.client.start()

    def _publish(self, sample: WrenchSample) -> None:
        if not self.active:
            return
        now = self.new_stamp_ns(TOPIC_WRENCH)
        if now is None:
            return      # no valid stamp yet, or the same instant as the previous record
        w = sample.wrench
        self.publisher.publish(wrench_stamped(now, self.frame(self.params['frame_id']), w[:3],
                                              w[3:]))

    def _on_bias(self, request: Trigger.Request, response: Trigger.Response
                 ) -> Trigger.Response:
        if self.client is None or not self.configured:
            response.success, response.message = False, 'not configured: no link to the box'
            return response
        try:
            bias = self.client.set_host_bias()
        except RuntimeError as exc:
            response.success, response.message = False, str(exc)
        else:
            response.success = True
            response.message = 'bias [N, N m]: ' + ' '.join(f'{v:+.4f}' for v in bias)
        self.get_logger().info(f'bias: {response.message}')
        return response


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(FtBridge, args))


if __name__ == '__main__':
    main()
