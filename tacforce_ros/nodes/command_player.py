"""command_player: plays a force command sequence on /force_controller/desired.

Publishes geometry_msgs/Vector3Stamped at `rate_hz` on the node clock (sim time when
use_sim_time is true), from start-up (`autostart`) or from a call to ~/start (std_srvs/Trigger;
a call while playing restarts the sequence). After the last segment it publishes the final value
once and stops, unless `loop` is true. The sequence's t = 0 waits until `min_subscribers`
subscriptions listen on the topic (a session: the controller and the recorder), so neither
misses its start to a late start-up.
"""
from __future__ import annotations

import sys

from geometry_msgs.msg import Vector3Stamped
from std_srvs.srv import Trigger

from tacforce_ros.control.command_sequence import ForceSequence, SequenceError
from tacforce_ros.nodes.node_base import TacforceNode
from tacforce_ros.nodes.parameters import FRAME_PREFIX, ParamSpec, ParameterError
from tacforce_ros.nodes.qos import publisher_qos
from tacforce_ros.nodes.runner import run_node
from tacforce_ros.rig import RATE_HZ
from tacforce_ros.topics import TOPIC_DESIRED, relative



class CommandPlayer(TacforceNode):
    """Plays a force command sequence (config/commands/*.yaml) on /force_controller/desired."""

    NODE_NAME = 'command_player'
    PARAMETERS = (
        ParamSpec('sequence', 'paper_70s', 'command sequence: a YAML path or a name in '
                  'config/commands/'),
        ParamSpec('rate_hz', RATE_HZ, 'publication rate (Hz)', range=(1.0, 1000.0)),
        ParamSpec('frame_id', '', 'frame of the published forces; empty = the sequence\'s own'),
        FRAME_PREFIX,
        ParamSpec('loop', False, 'start over at the end of the sequence'),
        ParamSpec('autostart', True, 'start playing at start-up; else wait for ~/start'),
        ParamSpec('min_subscribers', 1, 'start the sequence once this many subscriptions '
                  'listen on the desired-force topic', range=(0, 100)),
    )

    def __init__(self, **node_options) -> None:
        super().__init__(**node_options)
        try:
            self.sequence = ForceSequence.load(self.params['sequence'])
        except SequenceError as exc:
            raise ParameterError(f'sequence: {exc}') from None
        self.frame_id = self.frame(self.params['frame_id'] or self.sequence.frame_id)
        self.publisher = self.create_publisher(Vector3Stamped, relative(TOPIC_DESIRED),
                                               publisher_qos(TOPIC_DESIRED))
        self.create_service(Trigger, '~/start', self._on_start)
        self._started_ns: int | None = None
        self._start_requested = False
        self.timer = self.create_timer(1.0 / self.params['rate_hz'], self._tick)
        self.get_logger().info(
            f'sequence {self.sequence.source}: {self.sequence.duration:.1f} s in '
            f'{self.frame_id} at {self.params["rate_hz"]:g} Hz, loop={self.params["loop"]}')
        if self.params['autostart']:
            self._start()

    def _start(self) -> None:
        # The sequence's t = 0 is taken at the next tick: with use_sim_time the clock reads 0
        # until the first /clock message, and timers only fire once it runs.
        self._start_requested = True

    def _on_start(self, request: Trigger.Request, response: Trigger.Response
                  ) -> Trigger.Response:
        restarted = self._started_ns is not None or self._start_requested
        self._start()
        response.success = True
        response.message = ('restarted' if restarted else 'started') + \
            f' {self.sequence.source} ({self.sequence.duration:.1f} s)'
        return response

    def _tick(self) -> None:
        now = self.get_clock().now()
        if self._start_requested and (self.publisher.get_subscription_count()
                                      < self.params['min_subscribers']):
            self.get_logger().info(f'waiting for {self.params["min_subscribers"]} subscribers '
                                   f'on {self.topic_name(TOPIC_DESIRED)}',
                                   throttle_duration_sec=5.0)
            return
        if self._start_requested:
            self._start_requested = False
            self._started_ns = now.nanoseconds
            self.get_logger().info('playing')
        if self._started_ns is None:
            return
        t = (now.nanoseconds - self._started_ns) * 1e-9
        finished = t >= self.sequence.duration
        if finished and self.params['loop']:
            t %= self.sequence.duration
            finished = False
        force = self.sequence.force_at(t)
        msg = Vector3Stamped()
        msg.header.stamp = now.to_msg()
        msg.header.frame_id = self.frame_id
        msg.vector.x, msg.vector.y, msg.vector.z = (float(v) for v in force)
        self.publisher.publish(msg)
        if finished:
            self._started_ns = None
            self.get_logger().info('sequence finished')


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(CommandPlayer, args))


if __name__ == '__main__':
    main()
