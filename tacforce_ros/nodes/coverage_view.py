"""coverage_view: the operator's live view of a calibration session's coverage.

Subscribes to /calibration/sample (sync_recorder's synchronised tactile frame, F/T wrench and
joint state of the pressed array) and every `period` wall seconds prints how the session so far
meets the campaign's coverage limits (recording/campaign.py: the same judgement the closed bag
gets): elapsed against the planned length, peak force, the shear directions pressed, the rests,
and what is still missing ("press harder", "vary the push direction", "let go between
presses"). On a terminal the view redraws in place; otherwise (a launch log) a view is
printed below the last when samples came since. The hand is the campaign's unless `hand_config`
names one. The limits are the campaign's (`campaign`: its folder) or the defaults.
A new array in the samples, or stamps that go back (a new session), starts a new view.
"""
from __future__ import annotations

import sys
import time

import numpy as np
from rclpy.clock import Clock, ClockType
from tacforce_msgs.msg import CalibrationSample

from tacforce_ros.hand.description import hand_config
from tacforce_ros.nodes.node_base import TacforceNode
from tacforce_ros.nodes.parameters import (HAND_CONFIG, ParamSpec, ParameterError, hand_parameter,
                                           kinematics_parameter)
from tacforce_ros.nodes.qos import subscriber_qos
from tacforce_ros.nodes.runner import run_node
from tacforce_ros.nodes.messages import stamp_ns
from tacforce_ros.recording.campaign import (CampaignError, CampaignPlan, CoverageLimits,
                                             LiveCoverage, coverage_view)
from tacforce_ros.topics import TOPIC_SAMPLE, relative

DRAIN_S = 0.5           # the most a stop waits for queued samples (a stop must take < 2 s)


class CoverageViewNode(TacforceNode):
    NODE_NAME = 'coverage_view'
    PARAMETERS = (
        HAND_CONFIG,
        ParamSpec('campaign', '', 'campaign folder whose coverage limits apply; empty: the '
                  'default limits'),
        ParamSpec('plate', '', 'plate pressed (shown in the title)'),
        ParamSpec('session_seconds', 0.0, 'planned session length (s) for the progress bar; '
                  '0: the campaign\'s for the array pressed, else none', range=(0.0, 1e6)),
        ParamSpec('period', 1.0, 'redraw every this many wall seconds', range=(0.05, 60.0)),
    )

    def __init__(self, **node_options) -> None:
        super().__init__(**node_options)
        p = self.params
        self.limits, self.planned = CoverageLimits(), p['session_seconds']
        self.plan: CampaignPlan | None = None
        hand_params = dict(p)
        if p['campaign']:
            try:
                plan = CampaignPlan.load(p['campaign'])
            except (CampaignError, OSError) as exc:
                raise ParameterError(f'campaign: {exc}') from None
            self.limits, self.plan = plan.limits, plan
            hand_params['hand_config'] = p['hand_config'] or str(hand_config(plan.hand_side))
        self.hand = hand_parameter(hand_params)
        if p['campaign'] and self.hand.side != plan.hand_side:
            raise ParameterError(f'campaign: a campaign of the {plan.hand_side} hand, '
                                 f'hand_config is the {self.hand.side} hand\'s')
        # Only rotations are asked of the kinematics: gravity does not matter.
        self.kin = kinematics_parameter(self.hand, {'gravity': (0.0, 0.0, -9.81)})
        self.live: LiveCoverage | None = None
        self.array = ''
        self.first_ns = self.last_ns = 0
        self.drawn_lines = 0
        self.drawn_samples = -1
        self.tty = sys.stdout.isatty()
        self.create_subscription(CalibrationSample, relative(TOPIC_SAMPLE), self._on_sample,
                                 subscriber_qos(TOPIC_SAMPLE))
        self.create_timer(p['period'], self._draw, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _on_sample(self, msg: CalibrationSample) -> None:
        t = stamp_ns(msg.header.stamp)
        name = msg.tactile.name
        if name != self.array or t < self.last_ns:
            try:
                array = self.hand.array(name)
            except KeyError:
                return
            self.array, self.first_ns = name, t
            limits = self.limits if self.plan is None else self.plan.limits_for(name)
            self.live = LiveCoverage(self.kin, self.hand.ft_frame, array.frame_id, limits)
        order = {joint: i for i, joint in enumerate(msg.joints.name)}
        tactile = msg.tactile
        if not set(self.kin.joint_names) <= set(order) or not (
                len(tactile.x) == len(tactile.y) == len(tactile.z) > 0):
            return
        q = np.array([msg.joints.position[order[j]] for j in self.kin.joint_names])
        f = msg.wrench.wrench.force
        self.live.add(np.stack([tactile.x, tactile.y, tactile.z], axis=1), (f.x, f.y, f.z), q)
        self.last_ns = t

    def view(self) -> str:
        title = (self.array or '(no samples yet)') + (f' on {self.params["plate"]}'
                                                        if self.params['plate'] else '')
        coverage = None if self.live is None else self.live.coverage()
        planned = self.planned or (self.plan.session_seconds(self.array)
                                   if self.plan is not None and self.array else 0.0)
        limits = self.limits if self.live is None else self.live.limits
        return coverage_view(title, coverage, limits, (self.last_ns - self.first_ns) * 1e-9,
                             planned)

    def _draw(self) -> None:
        samples = 0 if self.live is None else self.live.samples
        if not self.tty and samples == self.drawn_samples:
            return          # a log (launch's screen) gets a view only when there is news
        self.drawn_samples = samples
        text = self.view()
        if self.tty and self.drawn_lines:
            sys.stdout.write(f'\x1b[{self.drawn_lines}F\x1b[J')    # back to the last view
        sys.stdout.write(text + ('\n' if self.tty else '\n\n'))
        sys.stdout.flush()
        self.drawn_lines = text.count('\n') + 1

    def leave_safe(self) -> None:
        # Stopped with the session, right after the recorder's last samples: those already
        # received are judged first (until the queue is empty, DRAIN_S at most).
        executor = self.executor
        deadline = time.monotonic() + DRAIN_S
        while executor is not None and time.monotonic() < deadline:
            before = 0 if self.live is None else self.live.samples
            executor.spin_once(timeout_sec=0.02)
            if (0 if self.live is None else self.live.samples) == before:
                break
        self.drawn_samples = -1
        self._draw()        # the session as it ended
        coverage = None if self.live is None else self.live.coverage()
        if coverage is not None:
            self.get_logger().info(
                f'{self.array}: {coverage.samples} samples, ' + ('coverage enough' if coverage.ok
                                                                 else '; '.join(coverage.problems)))


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(CoverageViewNode, args))


if __name__ == '__main__':
    main()
