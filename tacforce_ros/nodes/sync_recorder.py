"""sync_recorder: records a calibration session into a rosbag2 (mcap) bag.

Subscribes to /tactile/raw, /ft_sensor/wrench and /joint_states; while recording it writes the
three raw streams and the synchronised /calibration/sample stream (approximate time,
`queue_size` and `slop`; the sample carries the selected array's TactileArray), which it also
publishes. It also writes, as they arrive, the closed-loop streams when a graph publishes them:
/force_controller/desired (f_d), /force_controller/state (the controller's every tick) and the
simulator's ground truth /sim/contact_force, so a closed-loop bag carries command, estimate and
truth on the one clock (a grasp's: /grasp_controller/state, the truth per fingertip and
/sim/object_pose); it subscribes to /force_controller/desired only once it records all
three input streams, so a command_player that waits for it starts when the bag has everything.
Bag layout and session metadata: docs/CONTRACTS.md. The bag is what `ros2 bag record -s mcap`
writes (one MCAP file unless `max_bag_size` or `max_bag_duration` splits it); an MCAP chunk ends
every `flush_seconds` (wall time), so a recorder killed with SIGKILL leaves every message up to
then on disk, and `bag_repair BAG` makes the bag whole. Services: ~/start
(tacforce_msgs/srv/StartRecording; empty fields take the parameters) and ~/stop
(std_srvs/Trigger).

Log times are the node clock's. Under use_sim_time the clock reads 0 until the first /clock, so
nothing is recorded before it: `autostart` starts the session at the first /clock, and ~/start
is refused until then (no message enters a bag with log time 0).

The subscriptions are raw: the CDR bytes as received go into the bag untouched (as rosbag2
records), and only the stamps and the sample's parts are decoded, with the bag's own typestore.
(rclpy's serialize_message is no substitute: with Fast DDS it returns the rmw's size
estimate, e.g. 76 bytes for a 68-byte JointState, and rosbags refuses the trailing bytes.)
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

from geometry_msgs.msg import PoseStamped, Vector3Stamped, WrenchStamped
from rclpy.clock import Clock, ClockType
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from tacforce_msgs.msg import CalibrationSample, ControllerState, TactileHand
from tacforce_msgs.srv import StartRecording

from tacforce_ros.bagio import (TOPIC_TYPES, BagError, CalibrationBagWriter, calibration_sample,
                                session_metadata, typestore)
from tacforce_ros.nodes.node_base import TacforceNode
from tacforce_ros.nodes.parameters import HAND_CONFIG, ParamSpec, ParameterError, hand_parameter
from tacforce_ros.nodes.qos import publisher_qos, subscriber_qos
from tacforce_ros.nodes.runner import run_node
from tacforce_ros.recording.synchroniser import ApproximateTimeSynchroniser
from tacforce_ros.topics import (TOPIC_CONTROLLER_STATE, TOPIC_DESIRED, TOPIC_GRASP_STATE,
                                 TOPIC_JOINTS, TOPIC_SAMPLE, TOPIC_SIM_CONTACT, TOPIC_SIM_OBJECT,
                                 TOPIC_TACTILE, TOPIC_WRENCH, relative)

INPUTS = (TOPIC_TACTILE, TOPIC_WRENCH, TOPIC_JOINTS)   # synchroniser input order
# Written as received, outside the samples: present only when the graph publishes them.
PASSTHROUGH = {TOPIC_DESIRED: (Vector3Stamped, 'geometry_msgs/msg/Vector3Stamped'),
               TOPIC_CONTROLLER_STATE: (ControllerState, 'tacforce_msgs/msg/ControllerState'),
               TOPIC_SIM_CONTACT: (WrenchStamped, TOPIC_TYPES[TOPIC_SIM_CONTACT]),
               TOPIC_GRASP_STATE: (ControllerState, 'tacforce_msgs/msg/ControllerState'),
               TOPIC_SIM_OBJECT: (PoseStamped, 'geometry_msgs/msg/PoseStamped')}
BAG_TOPICS = {**TOPIC_TYPES, **{topic: name for topic, (_, name) in PASSTHROUGH.items()}}
# Best-effort like every sensor consumer, but a deep history: a busy CPU must not cost samples
# (depth 5 lost ~20 % here under load); 200 = 2 s of tactile frames, 0.2 s of wrench at 1 kHz.
RECORDER_DEPTH = 200


class SyncRecorder(TacforceNode):
    """Records tactile, wrench and joint streams plus synchronised calibration samples."""

    NODE_NAME = 'sync_recorder'
    PARAMETERS = (
        ParamSpec('output_dir', 'bags', 'folder that receives one bag folder per session'),
        ParamSpec('flush_seconds', 1.0, 'end an MCAP chunk and hand it to the file this often '
                  '(s, wall time): the most a killed recorder can lose', range=(0.05, 3600.0)),
        ParamSpec('max_bag_size', 0, 'start a new file of the bag at this size (bytes, as '
                  '`ros2 bag record --max-bag-size`); 0: no split', range=(0, 2**62)),
        ParamSpec('max_bag_duration', 0.0, 'start a new file of the bag after this many seconds '
                  'of log time (as `ros2 bag record --max-bag-duration`); 0: no split',
                  range=(0.0, 1e9)),
        ParamSpec('queue_size', 100, 'approximate-time queue per input (messages)',
                  range=(1, 10000)),
        ParamSpec('slop', 0.005, 'largest stamp spread inside one sample (s)',
                  range=(0.0, 1.0)),
        ParamSpec('array', 'index_tip', 'array pressed on the plate (config/hand names)'),
        ParamSpec('plate', '', 'push-plate or object (button, flat, fillet, convex, edge, ...)'),
        ParamSpec('operator_notes', '', 'free text stored in the session metadata'),
        ParamSpec('source', 'lab', 'where the data comes from', choices=('lab', 'sim')),
        ParamSpec('scene', '', 'simulation: the scene sim_world runs (session metadata)'),
        ParamSpec('seed', -1, 'simulation: the simulator seed for the session metadata; -1 = '
                  'the scene\'s own (stored empty)', range=(-1, 2**32 - 1)),
        HAND_CONFIG,
        ParamSpec('autostart', False, 'start recording at start-up with the parameters above'),
    )

    def __init__(self, **node_options) -> None:
        super().__init__(**node_options)
        self.hand = hand_parameter(self.params)
        problem = self._array_problem(self.params['array'])
        if problem:
            raise ParameterError(problem)
        self.writer: CalibrationBagWriter | None = None
        self.sync: ApproximateTimeSynchroniser | None = None
        # Built now, not by the first recording: that ran inside an executor callback, where a
        # stop waited for it (up to 1 s on a loaded machine, bench_stop).
        typestore()
        self._array_name = ''
        self._counts: dict[str, int] = {}
        self._missing_array = 0
        self._undecodable = 0
        self.sample_publisher = self.create_publisher(CalibrationSample, relative(TOPIC_SAMPLE),
                                                      publisher_qos(TOPIC_SAMPLE))
        for index, (topic, msg_type) in enumerate(zip(
                INPUTS, (TactileHand, WrenchStamped, JointState))):
            self.create_subscription(msg_type, relative(topic), self._callback(index, topic),
                                     subscriber_qos(topic, depth=RECORDER_DEPTH), raw=True)
        for topic in PASSTHROUGH:
            if topic != TOPIC_DESIRED:
                self._subscribe_passthrough(topic)
        # The command topic is subscribed to once every input stream is being recorded: a
        # command_player waiting for the recorder among its subscribers (min_subscribers) then
        # starts a sequence only when the bag has everything. Subscribed from the start, it let
        # a sequence start while the F/T stream had not yet reached the recorder (DDS discovery
        # on a loaded host: 0.5 s of simulated F/T missing, too few readings to zero it).
        self._desired_subscription = None
        self.create_service(StartRecording, '~/start', self._on_start)
        self.create_service(Trigger, '~/stop', self._on_stop)
        # Flushing is about wall time (what a crash can lose), not sim time: a steady timer
        # flushes a quiet stream too (a busy one is flushed by its writes, on the same period).
        self.create_timer(self.params['flush_seconds'], self._flush,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._autostart_timer = None

    def on_built(self) -> None:
        # Recording opens a bag: not before the node is built (a stop while it is built ends
        # the process there, run_nodes).
        if self.params['autostart']:
            if self.now_ns() > 0:
                self._autostart()
            else:       # a timer on the node clock fires once /clock runs
                self.get_logger().info('autostart: recording starts at the first /clock')
                self._autostart_timer = self.create_timer(0.001, self._autostart)

    def _autostart(self) -> None:
        if self._autostart_timer is not None:
            self.destroy_timer(self._autostart_timer)
            self._autostart_timer = None
        ok, message = self.start(self.params['array'], self.params['plate'],
                                 self.params['operator_notes'])
        if not ok:
            raise ParameterError(message)

    def _array_problem(self, name: str) -> str | None:
        names = [a.name for a in self.hand.arrays]
        return None if name in names else f'array: {name!r} is not an array of this hand {names}'

    # --- session ---------------------------------------------------------------------------

    def start(self, array: str, plate: str, notes: str) -> tuple[bool, str]:
        if self.writer is not None:
            return False, f'already recording into {self.writer.path}'
        problem = self._array_problem(array)
        if problem:
            return False, problem
        started_ns = self.now_ns()
        if started_ns <= 0:
            return False, 'no clock yet (use_sim_time and no /clock): nothing could be stamped'
        folder = Path(self.params['output_dir']).expanduser()
        # Bag names use wall-clock date for people; stamps inside use the node clock.
        stem = f'{time.strftime("%Y%m%d_%H%M%S")}_{array}' + (f'_{plate}' if plate else '')
        path, n = folder / stem, 1
        while path.exists():
            path, n = folder / f'{stem}_{n}', n + 1
        meta = session_metadata(array=array, plate=plate, hand_side=self.hand.side,
                                operator_notes=notes, source=self.params['source'],
                                scene=self.params['scene'],
                                seed=self.params['seed'] if self.params['seed'] >= 0 else '')
        try:
            folder.mkdir(parents=True, exist_ok=True)
            self.writer = CalibrationBagWriter(path, meta, started_ns=started_ns,
                                               flush_seconds=self.params['flush_seconds'],
                                               max_bag_size=self.params['max_bag_size'],
                                               max_bag_duration=self.params['max_bag_duration'],
                                               topics=BAG_TOPICS)
        except (OSError, BagError) as exc:
            return False, f'cannot create bag {path}: {exc}'
        self.sync = ApproximateTimeSynchroniser(len(INPUTS), self.params['queue_size'],
                                                self.params['slop'])
        self._array_name = array
        self._counts = dict.fromkeys((*INPUTS, TOPIC_SAMPLE, *PASSTHROUGH), 0)
        self._missing_array = self._undecodable = 0
        self.get_logger().info(f'recording {array} on {plate or "?"} into {path}')
        return True, str(path)

    def stop(self) -> tuple[bool, str]:
        if self.writer is None:
            return False, 'not recording'
        writer, self.writer = self.writer, None
        writer.close()
        dropped = dict(zip(INPUTS, self.sync.dropped))
        summary = (f'closed {writer.path}: written {self._counts}, dropped by the synchroniser '
                   f'{dropped}, frames without {self._array_name}: {self._missing_array}, '
                   f'undecodable: {self._undecodable}')
        self.get_logger().info(summary)
        return True, summary

    def _on_start(self, request: StartRecording.Request, response: StartRecording.Response
                  ) -> StartRecording.Response:
        ok, message = self.start(request.array or self.params['array'],
                                 request.plate or self.params['plate'],
                                 request.operator_notes or self.params['operator_notes'])
        response.success, response.message = ok, message
        response.bag_path = message if ok else ''
        return response

    def _on_stop(self, request: Trigger.Request, response: Trigger.Response
                 ) -> Trigger.Response:
        response.success, response.message = self.stop()
        return response

    def leave_safe(self) -> None:
        if self._autostart_timer is not None:   # still waiting for /clock: it will not start now
            self.destroy_timer(self._autostart_timer)
            self._autostart_timer = None
        self.stop()

    def _flush(self) -> None:
        if self.writer is not None:
            self.writer.flush()

    # --- streams ---------------------------------------------------------------------------

    def _callback(self, index: int, topic: str):
        msgtype = TOPIC_TYPES[topic]

        def receive(data: bytes) -> None:
            if self.writer is None:
                return
            self._write(topic, data)
            try:
                msg = typestore().deserialize_cdr(data, msgtype)
            except Exception as exc:    # noqa: BLE001 - rosbags raises several kinds
                self._undecodable += 1
                self.get_logger().warning(f'{topic}: undecodable message dropped from the '
                                          f'samples ({exc})', throttle_duration_sec=5.0)
                return
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            matched = self.sync.add(index, stamp, msg)
            if matched is not None:
                self._write_sample(*matched)
        return receive

    def _subscribe_passthrough(self, topic: str):
        msg_type = PASSTHROUGH[topic][0]
        return self.create_subscription(msg_type, relative(topic), self._passthrough(topic),
                                        subscriber_qos(topic, depth=RECORDER_DEPTH), raw=True)

    def _passthrough(self, topic: str):
        def receive(data: bytes) -> None:
            if self.writer is not None:
                self._write(topic, data)
        return receive

    def _write(self, topic: str, data: bytes) -> None:
        self.writer.write_serialized(topic, self.now_ns(), data)
        self._counts[topic] += 1
        if self._desired_subscription is None and all(self._counts[t] for t in INPUTS):
            self._desired_subscription = self._subscribe_passthrough(TOPIC_DESIRED)
            self.get_logger().info('recording every input: listening to '
                                   f'{self.topic_name(TOPIC_DESIRED)}')

    def _write_sample(self, hand, wrench, joints) -> None:
        """hand, wrench, joints: rosbags messages; the sample is published as CDR bytes."""
        tactile = next((a for a in hand.arrays if a.name == self._array_name), None)
        if tactile is None:
            self._missing_array += 1
            return
        stamp = hand.header.stamp.sec * 1_000_000_000 + hand.header.stamp.nanosec
        sample = calibration_sample(stamp, tactile, wrench, joints)
        data = bytes(typestore().serialize_cdr(sample, TOPIC_TYPES[TOPIC_SAMPLE]))
        self.sample_publisher.publish(data)
        self._write(TOPIC_SAMPLE, data)


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(SyncRecorder, args))


if __name__ == '__main__':
    main()
