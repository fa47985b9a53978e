"""estimator: /tactile/raw -> calibrated 3-D contact forces of every array with a model.

One batched RuntimeEstimator pass per tactile frame publishes
* /tactile/<array>/wrench (geometry_msgs/WrenchStamped, frame = the array frame {S0}, stamp =
  the tactile frame's) for each valid estimate: the topics users subscribe to;
* /tactile/estimates (tacforce_msgs/ForceEstimateArray) with validity, status and OOD score;
* /tactile/markers (visualization_msgs/MarkerArray, force arrows) at `marker_rate_hz`.

Models come from `model_config` (a YAML listing one model file per array, see
estimation/model_set.py); arrays without a model are skipped, and said so at start-up.
A watchdog timer on the node clock (sim time under use_sim_time), restarted by every frame, fires
only when no frame came for `stale_timeout`: it then publishes estimates flagged invalid (status
"stale") at `stale_check_rate_hz` until frames return, so consumers and the force controller go
safe; the per-array wrench topics stay silent meanwhile (a WrenchStamped cannot say "invalid").
While frames flow it never wakes the executor.
~/tare (std_srvs/Trigger) re-estimates the taxel offsets from the next `tare_frames` frames
(nothing may touch the arrays meanwhile). With `tare_file`, every tare is saved there, and an
estimator that starts while the file exists loads it instead of taring at start: one that
restarts mid-session (a crash, a respawn) must not tare on arrays that are touching something.
`lowpass_hz` > 0 low-passes every input channel causally (Butterworth of `lowpass_order`, designed
for frames at `frame_rate_hz`; estimation/causal_filter.py): less noise on the estimate, at the
price of the filter's group delay, logged at start-up, which the controller sees. Off by default.

Per frame the node handles bytes, not message objects: /tactile/raw is taken serialized and
decoded by one precomputed gather (serialized.TactileHandDecoder), and the 19 outgoing messages
are serialized layouts made at start-up whose stamps and numbers are overwritten
(serialized.SerializedMessages; `bench_messages` measures what this saves). Objects made at
start-up are frozen out of the garbage collector's full passes, which otherwise stall a frame by
milliseconds now and then.

Executor: rclpy's EventsExecutor where it exists (Jazzy and later, rclpy.experimental), which
dispatches each frame without rebuilding a wait set over every entity of the node; it keeps the
watchdog on the node clock (it re-plans timers on every /clock jump under use_sim_time). On
Humble the import fails and the node spins a SingleThreadedExecutor.
"""
from __future__ import annotations

import gc
import sys
import time
from pathlib import Path

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, WrenchStamped
from rclpy.clock import Clock, ClockType
from std_srvs.srv import Trigger
from tacforce_msgs.msg import ForceEstimateArray, TactileHand
from visualization_msgs.msg import Marker, MarkerArray

try:        # Iron and later
    from rclpy.event_handler import PublisherEventCallbacks
except ImportError:     # Humble
    from rclpy.qos_event import PublisherEventCallbacks

from tacforce_ros.estimation.causal_filter import FilterDesignError
from tacforce_ros.estimation.model_set import (ModelConfigError, TareWindow, default_model_config,
                                               load_model_set)
from tacforce_ros.estimation.preprocessing import SAMPLE_RATE_HZ
from tacforce_ros.estimation.taxel_health import FROZEN_FRAMES, OUT_OF_RANGE, TAXEL_STATUS
from tacforce_ros.nodes.node_base import TacforceNode
from tacforce_ros.nodes.parameters import (FRAME_PREFIX, HAND_CONFIG, ParamSpec, ParameterError,
                                           hand_parameter)
from tacforce_ros.nodes.qos import RELIABLE_QOS, publisher_qos, subscriber_qos
from tacforce_ros.nodes.realtime import REALTIME_PRIORITY
from tacforce_ros.nodes.runner import events_executor, run_node
from tacforce_ros.nodes.messages import stamp
from tacforce_ros.nodes.serialized import (SerializedMessages, TactileHandDecoder,
                                           serialized_estimates, serialized_wrenches)
from tacforce_ros.topics import (TOPIC_DIAGNOSTICS, TOPIC_ESTIMATES, TOPIC_MARKERS,
                                 TOPIC_TACTILE, array_wrench_topic, relative)

STATUS_STALE = 'stale'
# Frames the best-effort subscription keeps: a scheduling stall of a busy machine delays frames
# instead of losing them (bench_ros at 1 kHz, load 3-7 on 2 cores: 1 to 17 lost per 1000-3000
# with the sensor-data depth 5, none in 3 runs with 20); each frame keeps its own stamp, and a
# backlog clears at ~0.3 ms a frame.
FRAME_QUEUE_DEPTH = 20
FAULT_LOG_PERIOD_S = 1.0    # at most one line a second per array about its taxels



class Estimator(TacforceNode):
    """Per-array contact forces from whole-hand tactile frames, with staleness and tare."""

    NODE_NAME = 'estimator'
    PARAMETERS = (
        ParamSpec('model_config', '', 'YAML listing one model file per array; empty = '
                  'config/models/default.yaml (the left hand: config/models/left/default.yaml)'),
        HAND_CONFIG, FRAME_PREFIX,
        ParamSpec('stale_timeout', 0.025, 'input counted stale after this long without a '
                  'tactile frame (s, node clock)', range=(0.001, 10.0)),
        ParamSpec('stale_check_rate_hz', 200.0, 'invalid estimates per second while stale',
                  range=(1.0, 1000.0)),
        ParamSpec('marker_rate_hz', 10.0, 'force-arrow MarkerArray rate; 0 = off',
                  range=(0.0, 100.0)),
        ParamSpec('marker_scale', 0.02, 'arrow length per newton (m/N)', range=(1e-5, 1.0)),
        ParamSpec('tare_frames', 50, 'frames averaged by ~/tare', range=(1, 10000)),
        ParamSpec('tare_at_start', True, 'tare on the first tare_frames frames (the arrays '
                  'must be untouched at start-up); false keeps the model files\' offsets'),
        ParamSpec('tare_file', '', 'every tare is saved to this .npz, and loaded at start-up '
                  'when it exists instead of taring at start; empty = none'),
        ParamSpec('lowpass_hz', 0.0, 'causal low-pass cut-off of the input channels (Hz); '
                  '0 = off', range=(0.0, 1000.0)),
        ParamSpec('lowpass_order', 2, 'Butterworth order of that low-pass', range=(1, 8)),
        ParamSpec('frame_rate_hz', SAMPLE_RATE_HZ, 'tactile frame rate the low-pass is designed '
                  'for (Hz)', range=(1.0, 10000.0)),
        ParamSpec('frozen_frames', FROZEN_FRAMES, 'a taxel whose three channels stay unchanged '
                  'this many frames in a row is frozen and its array\'s estimate invalid; 0 = not '
                  'looked for', range=(0, 100000)),
        ParamSpec('out_of_range', OUT_OF_RANGE, 'an array whose standardised input |z| exceeds '
                  'this is far outside its calibration and its estimate invalid; 0 = never',
                  range=(0.0, 1e9)),
        ParamSpec('diagnostics_period', 1.0, 'taxel health on /diagnostics every this many wall '
                  'seconds; 0 = never', range=(0.0, 3600.0)),
        REALTIME_PRIORITY,
    )

    def __init__(self, **node_options) -> None:
        super().__init__(**node_options)
        p = self.params
        self.hand = hand_parameter(p)
        try:
            self.models = load_model_set(p['model_config'] or default_model_config(self.hand),
                                         self.hand)
        except (ModelConfigError, OSError) as exc:
            raise ParameterError(f'model_config: {exc}') from None
        try:
            self.models.estimator.set_lowpass(p['lowpass_hz'], p['frame_rate_hz'],
                                              p['lowpass_order'])
        except FilterDesignError as exc:
            raise ParameterError(f'lowpass_hz: {exc}') from None
        if p['frozen_frames'] == 1:
            raise ParameterError('frozen_frames: 1 would flag every taxel; 0 (off) or 2 and more')
        self.models.check_taxels(p['frozen_frames'] or None, p['out_of_range'] or np.inf)
        self.names = tuple(a.name for a in self.models.arrays)
        self._faults: dict[str, str] = {}      # array -> its latest taxel fault, this period
        self._faulty_frames = 0
        self._faulty_now: dict[str, str] = {}  # array -> its fault in the last frame (the log)
        self._fault_logged: dict[str, float] = {}  # array -> monotonic s of its last line
        if p['diagnostics_period'] > 0:
            self.diagnostics_publisher = self.create_publisher(
                DiagnosticArray, TOPIC_DIAGNOSTICS, publisher_qos(TOPIC_DIAGNOSTICS))
            self.create_timer(p['diagnostics_period'], self._report_taxels,
                              clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.frames = tuple(self.frame(a.frame_id) for a in self.models.arrays)
        # rclpy's default QoS-event handlers (incompatible QoS or type: a log line) would add two
        # waitables per publisher, 38 of the 42 an executor polls per frame; subscribers of these
        # topics still report an incompatible QoS on their side.
        quiet = PublisherEventCallbacks(use_default_callbacks=False)
        self.wrench_publishers = [
            self.create_publisher(WrenchStamped, relative(array_wrench_topic(n)),
                                  publisher_qos(array_wrench_topic(n)), event_callbacks=quiet)
            for n in self.names]
        self.estimates_publisher = self.create_publisher(
            ForceEstimateArray, relative(TOPIC_ESTIMATES), publisher_qos(TOPIC_ESTIMATES),
            event_callbacks=quiet)
        self.create_subscription(TactileHand, relative(TOPIC_TACTILE), self._on_frame,
                                 subscriber_qos(TOPIC_TACTILE, depth=FRAME_QUEUE_DEPTH),
                                 raw=True)
        self.create_service(Trigger, '~/tare', self._on_tare)
        self._stale_after_ns = int(p['stale_timeout'] * 1e9)
        self._stale_period_ns = int(1e9 / p['stale_check_rate_hz'])
        self._watchdog = self.create_timer(p['stale_timeout'], self._on_stale)
        if p['marker_rate_hz'] > 0:
            self.marker_publisher = self.create_publisher(MarkerArray, relative(TOPIC_MARKERS),
                                                          RELIABLE_QOS)
            self.create_timer(1.0 / p['marker_rate_hz'], self._publish_markers)
        self._last_force = np.zeros((len(self.names), 3))
        self._last_stamp_ns = 0
        self.decoder = TactileHandDecoder(self.hand)
        self.wrenches = serialized_wrenches(self.frames)
        self._estimate_layouts: dict[tuple[str, ...], SerializedMessages] = {}
        self._stale_force = np.zeros((len(self.names), 3))
        self._stale_valid = np.zeros(len(self.names), bool)
        self._stale_status = (STATUS_STALE,) * len(self.names)
        # Offsets drift with temperature and differ from the calibration day's (paper IV-A):
        # estimates are published only once the start-up tare is done.
        tare_loaded = self._load_tare_file()
        tare_at_start = p['tare_at_start'] and not tare_loaded
        self._tare_window = TareWindow(p['tare_frames']) if tare_at_start else None
        self._tared = not tare_at_start
        self.rejected = 0
        self.get_logger().info(
            f'{len(self.names)} arrays with models ('
            + ', '.join(f'{n}:{k}' for n, k in zip(self.names, self.models.kinds)) + ')'
            + (f'; no model, skipped: {", ".join(self.models.skipped)}'
               if self.models.skipped else ''))
        lowpass = self.models.estimator.lowpass
        if lowpass is not None:
            self.get_logger().info(
                f'input low-pass {lowpass.cutoff_hz:g} Hz, order {lowpass.order} at '
                f'{lowpass.rate_hz:g} frames/s: group delay '
                f'{lowpass.group_delay_s() * 1e3:.1f} ms')
        gc.freeze()

    # --- per frame -------------------------------------------------------------------------

    def _on_frame(self, raw: bytes) -> None:
        if self._watchdog.timer_period_ns != self._stale_after_ns:     # frames are back
            self._watchdog.timer_period_ns = self._stale_after_ns
        self._watchdog.reset()
        try:
            stamp_ns, counts = self.decoder.decode(raw)
        except ValueError as exc:
            self.rejected += 1      # counted and dropped; the stream goes on
            self.get_logger().warn(f'tactile frame refused ({self.rejected} so far): {exc}',
                                   throttle_duration_sec=5.0)
            return
        if self._tare_window is not None:
            self._collect_tare(counts)
        if not self._tared:
            return
        estimate = self.models.estimate(counts)
        self.wrenches.set_stamp(stamp_ns)
        self.wrenches.set('force', estimate.force)
        valid = estimate.valid
        if np.count_nonzero(valid) < valid.size or self._faulty_now:
            self._note_faults(estimate.status)
        for k, publisher in enumerate(self.wrench_publishers):
            if valid[k]:
                publisher.publish(self.wrenches.message(k))
        self.estimates_publisher.publish(self._estimates(
            stamp_ns, estimate.force, valid, estimate.status, estimate.ood_score))
        self._last_force = estimate.force
        self._last_stamp_ns = stamp_ns

    def _estimates(self, stamp_ns: int, force: np.ndarray, valid: np.ndarray,
                   status: tuple[str, ...], ood_score: np.ndarray | float) -> bytes:
        """Serialized ForceEstimateArray; one layout per distinct status tuple (a few: all ok,
        all stale, some arrays without finite input)."""
        layout = self._estimate_layouts.get(status)
        if layout is None:
            if len(self._estimate_layouts) >= 32:      # bounded, whatever the statuses
                self._estimate_layouts.clear()
            layout = self._estimate_layouts[status] = serialized_estimates(
                self.frame(self.hand.base_frame), self.names, self.frames, self.models.kinds,
                status)
        layout.set_stamp(stamp_ns)
        layout.set('force', force)
        layout.set('valid', valid)
        layout.set('ood_score', ood_score)
        return layout.message(0)

    # --- taxel health ----------------------------------------------------------------------

    def _note_faults(self, status: tuple[str, ...]) -> None:
        """Logs each array's taxel fault when it begins or changes, and when it ends; keeps
        the period's faults for /diagnostics."""
        now = {name: why for name, why in zip(self.names, status) if why.startswith(TAXEL_STATUS)}
        wall = time.monotonic()

        def may_log(name: str) -> bool:     # a taxel flickering at a rail: a line a second
            if wall - self._fault_logged.get(name, -np.inf) < FAULT_LOG_PERIOD_S:
                return False
            self._fault_logged[name] = wall
            return True

        for name, why in now.items():
            if self._faulty_now.get(name) != why and may_log(name):
                self.get_logger().warning(f'{name}: {why}; its estimate is invalid')
        for name in self._faulty_now.keys() - now.keys():
            if may_log(name):
                self.get_logger().info(f'{name}: taxels healthy again')
        self._faulty_now = now
        self._faults.update(now)
        self._faulty_frames += bool(now)

    def _report_taxels(self) -> None:
        """/diagnostics: WARN naming each array whose estimate a taxel fault made invalid in
        the period, OK otherwise."""
        faults, frames = self._faults, self._faulty_frames
        self._faults, self._faulty_frames = {}, 0
        if faults:
            level = DiagnosticStatus.WARN
            message = '; '.join(f'{n}: {w}' for n, w in faults.items())
        else:
            level, message = DiagnosticStatus.OK, 'no faulty taxel'
        status = DiagnosticStatus(
            level=level, name=f'{self.get_fully_qualified_name()}: taxels', message=message,
            hardware_id=self.hand.base_frame,
            values=[KeyValue(key=n, value=w) for n, w in faults.items()]
            + [KeyValue(key='faulty_frames', value=str(frames))])
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self.diagnostics_publisher.publish(array)

    # --- staleness -------------------------------------------------------------------------

    def _on_stale(self) -> None:
        self._watchdog.timer_period_ns = self._stale_period_ns
        # ood_score inf: no input at all is as far out of distribution as it gets
        self.estimates_publisher.publish(self._estimates(
            self.now_ns(), self._stale_force, self._stale_valid, self._stale_status, np.inf))

    # --- tare ------------------------------------------------------------------------------

    def _on_tare(self, request: Trigger.Request, response: Trigger.Response
                 ) -> Trigger.Response:
        self._tare_window = TareWindow(self.params['tare_frames'])
        response.success = True
        response.message = (f'taring {len(self.names)} arrays from the next '
                            f'{self.params["tare_frames"]} frames; keep them untouched')
        self.get_logger().info(response.message)
        return response

    def _collect_tare(self, counts: np.ndarray) -> None:
        if not self._tare_window.add(counts):
            return
        frames, self._tare_window = self._tare_window.take(), None
        try:
            self.models.set_tare(frames)
        except ValueError as exc:
            self.get_logger().error(f'tare refused, offsets unchanged: {exc}')
        else:
            self.get_logger().info(f'tare done from {len(frames)} frames')
            if self.params['tare_file']:
                try:
                    self.models.save_tare(self.params['tare_file'])
                except OSError as exc:
                    self.get_logger().error(f'tare not saved to {self.params["tare_file"]}: {exc}')
        self._tared = True

    def _load_tare_file(self) -> bool:
        """The session's saved tare, if there is one (True); refuses a file that does not fit.
        A tare_file that could not be written is refused before any frame is read."""
        path = Path(self.params['tare_file']) if self.params['tare_file'] else None
        if path is None:
            return False
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ParameterError(f'tare_file: cannot make its folder: {exc}') from None
        try:
            self.models.load_tare(path)
        except FileNotFoundError:
            return False
        except ValueError as exc:
            raise ParameterError(f'tare_file: {exc}') from None
        self.get_logger().info(f'tare loaded from {path} (no tare at start)')
        return True

    # --- markers ---------------------------------------------------------------------------

    def _publish_markers(self) -> None:
        out = MarkerArray()
        scale = self.params['marker_scale']
        for k, frame in enumerate(self.frames):
            marker = Marker(ns='tactile_force', id=k, type=Marker.ARROW, action=Marker.ADD)
            marker.header.stamp, marker.header.frame_id = stamp(self._last_stamp_ns), frame
            tip = self._last_force[k] * scale
            marker.points = [Point(), Point(x=float(tip[0]), y=float(tip[1]), z=float(tip[2]))]
            marker.scale.x, marker.scale.y, marker.scale.z = 0.001, 0.002, 0.003  # shaft, head (m)
            marker.color.r, marker.color.g, marker.color.a = 1.0, 0.3, 1.0
            marker.pose.orientation.w = 1.0
            out.markers.append(marker)
        self.marker_publisher.publish(out)


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(Estimator, args, executor=events_executor))


if __name__ == '__main__':
    main()
