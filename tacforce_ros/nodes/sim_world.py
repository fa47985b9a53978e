"""sim_world: the simulator of a scene behind the three device emulators, so that sim:=true swaps
the hardware and nothing else.

The drivers reach the emulators on 127.0.0.1 exactly as they reach the hardware: xela_server
(WebSocket, `xela_port`), Net F/T (RDT over UDP, `netft_port`) and the Allegro hand behind
socketcand (`can_port`). A stepping thread advances the simulator by one `dt` per period of
dt / `real_time_factor` wall seconds; torques the hand emulator receives drive closed-loop
scenes (calibration scenes follow their operator model and ignore torques). The emulators send
at their device rates times `real_time_factor`, so every rate holds in simulated time.

In closed-loop scenes simulated time starts when the hand's servos are first switched on (the
allegro_driver's start-up ends with SYSTEM_ON), with `start_with_servos`: the scene's t = 0 is
then the moment a controller can act, as in the in-process path, instead of the finger falling
limp while the other nodes start. Until then the emulators serve the initial state and /clock
repeats the initial time (about 20 times a wall second), so every node's clock is valid, and
the driver, which opens the hand only once its clock is, acts from the first simulated step.

With `publish_clock` it is the /clock source (rosgraph_msgs/Clock, simulated time, every
1/`clock_rate_hz` simulated seconds); it runs on wall time itself. /sim/contact_force carries the
simulator's ground truth (WrenchStamped in the array frame {S0}) at the tactile rate. Service
~/pause_tactile (std_srvs/SetBool): true stops the xela_server emulator (the server disappears,
as when it crashes), false brings it back on the same port.
"""
from __future__ import annotations

import sys
import threading

import numpy as np
from geometry_msgs.msg import WrenchStamped
from rosgraph_msgs.msg import Clock
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import SetBool

from tacforce_ros.hand.description import HandConfigError, load_hand
from tacforce_ros.nodes.common import (ParameterError, ParamSpec, TacforceNode, publisher_qos,
                                       run_node)
from tacforce_ros.nodes.messages import stamp, wrench_stamped
from tacforce_ros.sim import SceneError, make_simulator
from tacforce_ros.sim.emulators.allegro import AllegroEmulator
from tacforce_ros.sim.emulators.base import Pacer
from tacforce_ros.sim.emulators.netft import NetFtEmulator
from tacforce_ros.sim.emulators.xela_server import XelaServerEmulator
from tacforce_ros.topics import TOPIC_SIM_CONTACT

# /clock as rosgraph's own publishers offer it: best effort, keep-last 1 (only the newest matters).
CLOCK_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT,
                       durability=DurabilityPolicy.VOLATILE)


class SimWorld(TacforceNode):
    """Simulated hand, tactile arrays and F/T sensor behind the device emulators; /clock."""

    NODE_NAME = 'sim_world'
    PARAMETERS = (
        ParamSpec('scene', 'calibration_index_tip_spherical',
                  'scene: a name under config/scenes/ or a YAML path'),
        ParamSpec('seed', -1, 'simulator seed; -1 = the scene\'s own', range=(-1, 2**31 - 1)),
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
        ParamSpec('hand_config', '', 'hand description YAML; empty = the default hand'),
        ParamSpec('start_with_servos', True, 'closed-loop scenes: simulated time starts when '
                  'the hand\'s servos are first switched on (false: at start-up)'),
    )

    def __init__(self) -> None:
        super().__init__()
        p = self.params
        try:
            self.hand = load_hand(p['hand_config'] or None)
            self.sim = make_simulator(p['scene'], self.hand,
                                      None if p['seed'] < 0 else p['seed'])
        except (HandConfigError, SceneError, OSError) as exc:
            raise ParameterError(f'scene/hand_config: {exc}') from None
        scene = self.sim.scene
        self.array = self.hand.array(scene.array)
        self.takes_torques = scene.kind == 'closed_loop'
        rtf = p['real_time_factor']
        self._torques = np.zeros(16)
        self._latest = self._step()
        self._tactile = threading.Condition()
        self._tactile_count = 0                       # fresh tactile frames so far
        self._tactile_seen: dict[int, int] = {}       # per emulator client thread
        self._stop = threading.Event()
        self.clock_publisher = (self.create_publisher(Clock, '/clock', CLOCK_QOS)
                                if p['publish_clock'] else None)
        self.truth_publisher = self.create_publisher(WrenchStamped, TOPIC_SIM_CONTACT,
                                                     publisher_qos(TOPIC_SIM_CONTACT))
        # The emulator may poll at twice the frame rate: _tactile_frame waits for the next fresh
        # simulated frame, so the simulator (not the wall clock) sets the tactile rate.
        self.xela = XelaServerEmulator(self._tactile_frame, port=p['xela_port'],
                                       rate_hz=2.0 * scene.tactile_rate * rtf,
                                       model=self.hand.sensor_model or 'XR23AHRCPP')
        self.netft = NetFtEmulator(self._wrench_record, port=p['netft_port'],
                                   rate_hz=p['ft_rate_hz'] * rtf)
        self.allegro = AllegroEmulator(lambda: self._latest.q, self._take_torques,
                                       port=p['can_port'])
        self.create_service(SetBool, '~/pause_tactile', self._on_pause_tactile)
        self._clock_every = max(1, int(round(1.0 / (p['clock_rate_hz'] * self.sim.dt))))
        self._thread = threading.Thread(target=self._run, name='sim_world_step', daemon=True)
        self._thread.start()
        self.get_logger().info(
            f'scene {scene.name} ({scene.kind}, array {scene.array}, plate {scene.plate.name}) '
            f'at {rtf:g}x real time; xela {self.xela.url}, Net F/T udp 127.0.0.1:'
            f'{self.netft.address[1]}, socketcand tcp 127.0.0.1:{self.allegro.address[1]}')

    # --- emulator sources and sinks (called from the emulators' threads) ---------------------

    def _tactile_frame(self) -> tuple[np.ndarray, np.ndarray]:
        # Each client (one emulator thread per connection) gets every fresh frame exactly once;
        # a stalled simulator yields a repeat after 0.5 s rather than blocking shutdown.
        client = threading.get_ident()
        with self._tactile:
            seen = self._tactile_seen.get(client, self._tactile_count - 1)
            self._tactile.wait_for(lambda: self._tactile_count > seen or self._stop.is_set(),
                                   timeout=0.5)
            self._tactile_seen[client] = self._tactile_count
            sample = self._latest
        return sample.taxel_counts, sample.temperatures

    def _wrench_record(self) -> tuple[np.ndarray, int]:
        sample = self._latest
        return sample.ft_counts, sample.ft_status

    def _take_torques(self, tau: np.ndarray) -> None:
        self._torques = tau

    # --- stepping ---------------------------------------------------------------------------

    def _step(self):
        return self.sim.step(self._torques if self.takes_torques else None)

    def _run(self) -> None:
        if self.takes_torques and self.params['start_with_servos']:
            frozen = Clock(clock=stamp(int(round(self._latest.t * 1e9))))
            waited = 0
            while not self.allegro.servo_on:
                if self.clock_publisher is not None and waited % 10 == 0:
                    self.clock_publisher.publish(frozen)
                waited += 1
                if self._stop.wait(0.005):
                    return
            self.get_logger().info('servos on: simulated time starts')
        pacer = Pacer(self.params['real_time_factor'] / self.sim.dt)
        steps = 0
        while pacer.wait(self._stop):
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
            now_ns = int(round((sample.t + self.sim.dt) * 1e9))
            if self.clock_publisher is not None and steps % self._clock_every == 0:
                self.clock_publisher.publish(Clock(clock=stamp(now_ns)))
            if sample.tactile_fresh:
                self.truth_publisher.publish(wrench_stamped(
                    now_ns if self.clock_publisher is not None else self.now_ns(),
                    self.array.frame_id, sample.true_force))

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

    def on_shutdown(self) -> None:
        self._stop.set()
        with self._tactile:
            self._tactile.notify_all()
        self._thread.join(timeout=2.0)
        for emulator in (self.xela, self.netft, self.allegro):
            emulator.close()


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(SimWorld, args))


if __name__ == '__main__':
    main()
