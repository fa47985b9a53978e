"""sim_world: the simulator of a scene behind the three device emulators, so that sim:=true swaps
the hardware and nothing else.

The drivers reach the emulators on 127.0.0.1 exactly as they reach the hardware: xela_server
(WebSocket, `xela_port`), Net F/T (RDT over UDP, `netft_port`) and the Allegro hand behind
socketcand (`can_port`). A stepping thread advances the simulator by one `dt` per period of dt /
`real_time_factor` wall seconds at most; torques the hand emulator receives drive closed-loop
scenes (calibration scenes follow their operator model and ignore torques). The emulators send
at their device rates times `real_time_factor` in wall time, as devices that never stop talking
(the drivers' silence watchdogs run on wall time): when lockstep holds simulated time they
repeat the held state.

Lockstep (`lockstep`, default on): simulated time does not outrun the nodes that consume it. The
stepping thread advances only while every gated stream of the scene's kind has published a
message stamped within one of its own periods (an ongoing device stream: within nothing), plus
`lockstep_slack` and two steps, of the step's end (sim/lockstep.py): in closed-loop scenes the
controller's ticks (/force_controller/state), the estimate of the scene's array
(/tactile/<array>/wrench) and the joint states (/joint_states, ongoing), in calibration scenes
the recorder's samples (/calibration/sample). On a slow machine the run is then slower than
`real_time_factor` (an upper bound), never different. A stream joins with its first messages and
is released after `lockstep_silence` wall seconds of silence (a stopped node does not freeze the
world), rejoining when it speaks again; both are logged. lockstep false: free-running at
`real_time_factor` (latency work). The achieved factor is published on ~/real_time_factor
(std_msgs/Float64) and logged every `report_period` wall seconds, as a warning when below 0.9 of
what was asked, with how long each gated stream held time. `stop_after` > 0 ends the scene once
that many simulated seconds have run: time stands still, the devices are still served, and the
log line "scene done: ..." (session_plan.SCENE_DONE_MARKER) tells whoever runs the session to
stop the nodes, drivers first, so a session ends when its scene does. Stopped itself, it stops
simulated time at once and serves the devices until the drivers have let go (DEVICE_LINGER_S
at most): stopped together, as a session or launch stops them, a driver never sees its device
vanish.

In closed-loop scenes simulated time starts when the hand's servos are first switched on (the
allegro_driver's start-up ends with SYSTEM_ON), with `start_with_servos`: the scene's t = 0 is
then the moment a controller can act, as in the in-process path, instead of the finger falling
limp while the other nodes start. Until then the emulators serve the initial state and /clock
repeats the initial time (about 20 times a wall second), so every node's clock is valid, and
the driver, which opens the hand only once its clock is, acts from the first simulated step.

With `publish_clock` it is the /clock source (rosgraph_msgs/Clock, simulated time, every
1/`clock_rate_hz` simulated seconds); it runs on wall time itself. /sim/contact_force carries the
simulator's ground truth (WrenchStamped in the array frame {S0}) at the tactile rate; in a grasp
scene one per fingertip (each in its own {S0}), and /sim/object_pose the object's pose
(PoseStamped, base frame), which closes the loop through grasp_controller: lockstep gates on
/grasp_controller/state, each fingertip's wrench and the joints. Service
~/pause_tactile (std_srvs/SetBool): true stops the xela_server emulator (the server disappears,
as when it crashes), false brings it back on the same port.
"""
from __future__ import annotations

import sys
import threading
import time
from dataclasses import replace

import numpy as np
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rclpy.clock import Clock as RclpyClock
from rclpy.clock import ClockType
from rosgraph_msgs.msg import Clock
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64
from std_srvs.srv import SetBool
from sensor_msgs.msg import JointState
from tacforce_msgs.msg import CalibrationSample, ControllerState

from tacforce_ros.nodes.node_base import TacforceNode
from tacforce_ros.nodes.parameters import (FRAME_PREFIX, HAND_CONFIG, ParamSpec, ParameterError,
                                           hand_parameter)
from tacforce_ros.nodes.qos import RELIABLE_QOS, publisher_qos, subscriber_qos
from tacforce_ros.nodes.runner import run_node
from tacforce_ros.nodes.messages import stamp, wrench_stamped
from tacforce_ros.nodes.serialized import header_stamp_ns
from tacforce_ros.bringup.session_plan import SCENE_DONE_MARKER
from tacforce_ros.sim import SceneError, make_simulator
from tacforce_ros.sim.emulators.allegro import V4_HAND_INFO, AllegroEmulator
from tacforce_ros.sim.emulators.base import Pacer
from tacforce_ros.sim.emulators.netft import NetFtEmulator
from tacforce_ros.sim.emulators.xela_server import XelaServerEmulator
from tacforce_ros.sim.lockstep import RealTimeMeter, TimeGate
from tacforce_ros.topics import (TOPIC_CONTROLLER_STATE, TOPIC_GRASP_STATE, TOPIC_JOINTS,
                                 TOPIC_SAMPLE, TOPIC_SIM_CONTACT, TOPIC_SIM_OBJECT,
                                 array_wrench_topic, relative)

# /clock as rosgraph's own publishers offer it: best effort, keep-last 1 (only the newest matters).
CLOCK_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT,
                       durability=DurabilityPolicy.VOLATILE)
# While held, /clock repeats the current time this often (wall s): /clock is best effort, and a
# node whose copy was lost would otherwise never see the time its next tick is due.
HELD_CLOCK_REPEAT_S = 0.02
DEVICE_LINGER_S = 2.0   # the most a stop waits for the drivers to disconnect (wall s)
SLOW_FRACTION = 0.9     # an achieved factor below this fraction of the asked one is warned about


def lockstep_streams(scene) -> tuple[dict[str, type], dict[str, type], dict[str, float]]:
    """The streams (topic: type) whose consumers close a scene's loop, periodic and ongoing
    (sim/lockstep.py), and the periods (s) known in advance: lockstep waits for them. Closed
    loop: the controller's ticks (period learnt) and the estimate of the scene's array (its
    wrench topic, published for valid estimates only: the estimator's tare and a stopped tactile
    stream do not hold time; one per tactile frame), and the driver's joint intake (the hand
    streams whatever simulated time does); calibration: the recorder's samples (one per tactile
    frame). A stream of the tactile rate holds time from its first message: one that had to
    learn its period first let time run free while the estimator caught up after its tare
    (bench_graph's fault run: estimates stale for 0.1 s right after the tare)."""
    frame_period = 1.0 / scene.tactile_rate
    if scene.kind == 'grasp':
        wrenches = {array_wrench_topic(f'{f}_tip'): WrenchStamped for f in scene.grasp['fingers']}
        return ({TOPIC_GRASP_STATE: ControllerState, **wrenches}, {TOPIC_JOINTS: JointState},
                dict.fromkeys(wrenches, frame_period))
    if scene.kind == 'closed_loop':
        wrench = array_wrench_topic(scene.array)
        return ({TOPIC_CONTROLLER_STATE: ControllerState, wrench: WrenchStamped},
                {TOPIC_JOINTS: JointState}, {wrench: frame_period})
    return {TOPIC_SAMPLE: CalibrationSample}, {}, {TOPIC_SAMPLE: frame_period}


class SimWorld(TacforceNode):
    """Simulated hand, tactile arrays and F/T sensor behind the device emulators; /clock."""

    NODE_NAME = 'sim_world'
    PARAMETERS = (
        ParamSpec('scene', 'calibration_index_tip_spherical',
                  'scene: a name under config/scenes/ or a YAML path'),
        ParamSpec('seed', -1, 'simulator seed; -1 = the scene\'s own', range=(-1, 2**32 - 1)),
        ParamSpec('real_time_factor', 1.0, 'simulated seconds per wall second',
                  range=(0.05, 50.0)),
        ParamSpec('publish_clock', True, 'publish simulated time on /clock'),
        ParamSpec('clock_rate_hz', 1000.0, '/clock messages per simulated second (at most one '
                  'per simulator step)', range=(10.0, 10000.0)),
        ParamSpec('ft_rate_hz', 1000.0, 'Net F/T record rate in simulated time (Hz)',
                  range=(1.0, 7000.0)),
        ParamSpec('xela_port', 5000, 'xela_server emulator TCP port on 127.0.0.1 (0: any)',
                  range=(0, 65535)),
        ParamSpec('netft_port', 49152, 'Net F/T emulator UDP port on 127.0.0.1 (0: any)',
                  range=(0, 65535)),
        ParamSpec('can_port', 29536, 'socketcand (Allegro CAN) emulator TCP port on 127.0.0.1 '
                  '(0: any)', range=(0, 65535)),
        HAND_CONFIG, FRAME_PREFIX,
        ParamSpec('start_with_servos', True, 'closed-loop scenes: simulated time starts when '
                  'the hand\'s servos are first switched on (false: at start-up)'),
        ParamSpec('lockstep', True, 'simulated time waits for the nodes closing the loop '
                  '(false: free-running at real_time_factor)'),
        ParamSpec('lockstep_slack', 0.002, 'simulated time may run this far (plus two steps) '
                  'beyond one period of a gated stream\'s newest stamp (s)', range=(0.0, 1.0)),
        ParamSpec('lockstep_silence', 1.0, 'a gated stream silent this long no longer holds '
                  'simulated time until it speaks again (s, wall)', range=(0.1, 600.0)),
        ParamSpec('stop_after', 0.0, 'end the scene (time stands still, "scene done" logged) '
                  'after this many simulated seconds from the start of simulated time; '
                  '0 = run until stopped', range=(0.0, 1e6)),
        ParamSpec('report_period', 10.0, 'achieved real-time factor to the log and '
                  '~/real_time_factor every this many wall seconds', range=(0.5, 3600.0)),
    )

    def __init__(self, **node_options) -> None:
        super().__init__(**node_options)
        p = self.params
        self.hand = hand_parameter(p)
        try:
            self.sim = make_simulator(p['scene'], self.hand,
                                      None if p['seed'] < 0 else p['seed'])
        except (SceneError, OSError) as exc:
            raise ParameterError(f'scene: {exc}') from None
        scene = self.sim.scene
        self.array = self.hand.array(scene.array)
        self.takes_torques = scene.kind in ('closed_loop', 'grasp')
        rtf = p['real_time_factor']
        self._torques = np.zeros(16)
        self._latest = self._step()
        self._tactile = threading.Condition()
        self._tactile_count = 0                       # fresh tactile frames so far
        self._tactile_seen: dict[int, int] = {}       # per emulator client thread
        self._stop = threading.Event()
        self.clock_publisher = (self.create_publisher(Clock, '/clock', CLOCK_QOS)
                                if p['publish_clock'] else None)
        self.truth_publisher = self.create_publisher(WrenchStamped, relative(TOPIC_SIM_CONTACT),
                                                     publisher_qos(TOPIC_SIM_CONTACT))
        self.object_publisher = (self.create_publisher(PoseStamped, relative(TOPIC_SIM_OBJECT),
                                                       publisher_qos(TOPIC_SIM_OBJECT))
                                 if scene.kind == 'grasp' else None)
        # The emulator may poll at twice the frame rate: _tactile_frame waits for the next fresh
        # simulated frame, so the simulator (not the wall clock) sets the tactile rate.
        self.xela = XelaServerEmulator(self._tactile_frame, port=p['xela_port'],
                                       rate_hz=2.0 * scene.tactile_rate * rtf,
                                       model=self.hand.sensor_model or 'XR23AHRCPP')
        self.netft = NetFtEmulator(self._wrench_record, port=p['netft_port'],
                                   rate_hz=p['ft_rate_hz'] * rtf)
        self.allegro = AllegroEmulator(lambda: self._latest.q, self._take_torques,
                                       port=p['can_port'],
                                       hand_info=replace(V4_HAND_INFO, side=self.hand.side))
        self.create_service(SetBool, '~/pause_tactile', self._on_pause_tactile)
        self.gate = self._lockstep_gate() if p['lockstep'] else None
        self._scene_done = False
        self.meter = RealTimeMeter()
        self.factor_publisher = self.create_publisher(Float64, '~/real_time_factor',
                                                      RELIABLE_QOS)
        self.create_timer(p['report_period'], self._report,
                          clock=RclpyClock(clock_type=ClockType.STEADY_TIME))
        self._clock_every = max(1, int(round(1.0 / (p['clock_rate_hz'] * self.sim.dt))))
        self._thread = threading.Thread(target=self._run, name='sim_world_step', daemon=True)
        self._thread.start()
        self.get_logger().info(
            f'scene {scene.name} ({scene.kind}, array {scene.array}, plate {scene.plate.name}) '
            f'at up to {rtf:g}x real time, '
            + (f'lockstep with {", ".join(self.gate.streams)}' if self.gate else 'free-running')
            + f'; xela {self.xela.url}, Net F/T udp 127.0.0.1:'
            f'{self.netft.address[1]}, socketcand tcp 127.0.0.1:{self.allegro.address[1]}')

    # --- emulator sources and sinks (called from the emulators' threads) ---------------------

    def _tactile_frame(self) -> tuple[np.ndarray, np.ndarray, float]:
        # Each client (one emulator thread per connection) gets every fresh frame exactly once;
        # a stalled simulator yields a repeat after 0.5 s rather than blocking shutdown. The
        # server's clock is simulated time: a frame carries the time the clock reads for it
        # (the end of its step), which the driver maps onto its node clock.
        client = threading.get_ident()
        with self._tactile:
            seen = self._tactile_seen.get(client, self._tactile_count - 1)
            self._tactile.wait_for(lambda: self._tactile_count > seen or self._stop.is_set(),
                                   timeout=0.5)
            self._tactile_seen[client] = self._tactile_count
            sample = self._latest
        return sample.taxel_counts, sample.temperatures, sample.t + self.sim.dt

    def _wrench_record(self) -> tuple[np.ndarray, int]:
        sample = self._latest
        return sample.ft_counts, sample.ft_status

    def _take_torques(self, tau: np.ndarray) -> None:
        self._torques = tau

    # --- stepping ---------------------------------------------------------------------------

    def _step(self):
        return self.sim.step(self._torques if self.takes_torques else None)

    def _lockstep_gate(self) -> TimeGate:
        periodic, ongoing, periods = lockstep_streams(self.sim.scene)
        # A consumer stamps with its clock, which may still read the step before the data's
        # (that step's /clock can reach it after the data): a stamp, and the period learnt from
        # the stamps, can each be one step short, and two steps of slack keep the gate open.
        gate = TimeGate(list(periodic), self.params['lockstep_slack'] + 2.0 * self.sim.dt,
                        self.params['lockstep_silence'], ongoing=list(ongoing),
                        periods=periods, on_event=self._gate_event)
        for topic, message_type in {**periodic, **ongoing}.items():
            self.create_subscription(message_type, relative(topic),
                                     lambda raw, topic=topic: gate.heard(topic,
                                                                         header_stamp_ns(raw)),
                                     subscriber_qos(topic), raw=True)
        return gate

    def _gate_event(self, message: str) -> None:
        self.get_logger().warning(f'lockstep: {message}')

    def _publish_clock(self, t_ns: int) -> None:
        if self.clock_publisher is not None:
            self.clock_publisher.publish(Clock(clock=stamp(t_ns)))

    def _run(self) -> None:
        if self.takes_torques and self.params['start_with_servos']:
            frozen = int(round(self._latest.t * 1e9))
            waited = 0
            while not self.allegro.servo_on:
                if waited % 10 == 0:
                    self._publish_clock(frozen)
                waited += 1
                if self._stop.wait(0.005):
                    return
            self.get_logger().info('servos on: simulated time starts')
        dt = self.sim.dt
        self.meter.start(self._latest.t)
        if self.gate is not None:
            self.gate.start(int(round(self._latest.t * 1e9)))
        stop_at = (self._latest.t + self.params['stop_after'] if self.params['stop_after'] > 0
                   else float('inf'))
        pacer = Pacer(self.params['real_time_factor'] / dt)
        steps = 0
        while pacer.wait(self._stop):
            # The clock reads the end of the latest step; the next step ends one dt later.
            now_ns = int(round((self._latest.t + dt) * 1e9))
            if self.gate is not None:
                while not self.gate.wait(now_ns + int(round(dt * 1e9)), HELD_CLOCK_REPEAT_S):
                    if self._stop.is_set():
                        return
                    self._publish_clock(now_ns)
            try:
                sample = self._step()
            except Exception as exc:   # noqa: BLE001 - a dead simulator must be said, not hidden
                self.get_logger().fatal(f'simulator stopped: {type(exc).__name__}: {exc}')
                return
            with self._tactile:
                self._latest = sample
                if sample.tactile_fresh:
                    self._tactile_count += 1
                    self._tactile.notify_all()
            steps += 1
            # Time at the end of the step: the first /clock is dt, never the "unset" zero.
            now_ns = int(round((sample.t + dt) * 1e9))
            if steps % self._clock_every == 0:
                self._publish_clock(now_ns)
            if sample.tactile_fresh:
                self._publish_truth(sample, now_ns if self.clock_publisher is not None
                                    else self.now_ns())
            if sample.t + dt >= stop_at - 0.5 * dt:
                self._scene_done = True
                self.get_logger().info(f'{SCENE_DONE_MARKER} {self._summary()}')
                return

    def _publish_truth(self, sample, t_ns: int) -> None:
        """The contact force on the pressed array (a grasp: on each fingertip, in its own
        frame) and, in a grasp, the object's pose in the base frame."""
        if self.sim.scene.kind != 'grasp':
            self.truth_publisher.publish(wrench_stamped(
                t_ns, self.frame(self.hand.array(sample.pressed_array).frame_id
                                 if sample.pressed_array else self.array.frame_id),
                sample.true_force))
            return
        for finger, force in sample.finger_forces.items():
            self.truth_publisher.publish(wrench_stamped(
                t_ns, self.frame(self.hand.array(f'{finger}_tip').frame_id), force))
        pose = PoseStamped()
        pose.header.stamp = stamp(t_ns)
        pose.header.frame_id = self.frame(self.hand.base_frame)
        position, quaternion = sample.object_position, sample.object_quaternion
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = map(float, position)
        (pose.pose.orientation.w, pose.pose.orientation.x, pose.pose.orientation.y,
         pose.pose.orientation.z) = map(float, quaternion)
        self.object_publisher.publish(pose)

    # --- achieved real-time factor ------------------------------------------------------------

    def _summary(self) -> str:
        factor, simulated, wall = self.meter.overall(self._latest.t)
        text = (f'{simulated:.1f} s simulated in {wall:.1f} s wall, {factor:.2f}x real time '
                f'(asked {self.params["real_time_factor"]:g}x)')
        if self.gate is not None:
            text += '; held by ' + ', '.join(
                f'{s.name} {s.held_s:.1f} s' + (f' (released {s.releases}x)' if s.releases else '')
                for s in self.gate.streams.values())
        return text

    def _report(self) -> None:
        if self.meter.started is None or self._scene_done:
            return          # simulated time has not started (servos off), or has ended
        factor, wall = self.meter.window(self._latest.t)
        self.factor_publisher.publish(Float64(data=factor))
        text = (f'{factor:.2f}x real time over the last {wall:.1f} s; since the start '
                + self._summary())
        if factor < SLOW_FRACTION * self.params['real_time_factor']:
            self.get_logger().warning(f'simulation slower than asked: {text}')
        else:
            self.get_logger().info(text)

    def _on_pause_tactile(self, request: SetBool.Request, response: SetBool.Response
                          ) -> SetBool.Response:
        if request.data:
            self.xela.stop()
        else:
            self.xela.start()
        response.success = True
        response.message = 'xela_server stopped' if request.data else \
            f'xela_server serving on {self.xela.url}'
        self.get_logger().info(response.message)
        return response

    def leave_safe(self) -> None:
        if self.meter.started is not None and not self._scene_done:
            self.get_logger().info(f'stopped: {self._summary()}')
        self._stop.set()
        with self._tactile:
            self._tactile.notify_all()
        self._thread.join(timeout=2.0)
        # Devices outlive the graph that stops: the emulators serve until the drivers stopped
        # with this node have let go (a driver that saw its hand vanish first ended with code 1,
        # a lost link, in 1 of 4 test suites), DEVICE_LINGER_S at most.
        deadline = time.monotonic() + DEVICE_LINGER_S
        while (self.allegro.server.client_count or self.xela.client_count) and (
                time.monotonic() < deadline):
            time.sleep(0.01)
        for emulator in (self.xela, self.netft, self.allegro):
            emulator.close()


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(SimWorld, args))


if __name__ == '__main__':
    main()
