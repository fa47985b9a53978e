"""The closed loop on the thumb through the node graph (`session closed_loop --array thumb_tip`,
as `closed_loop.launch.py array:=thumb_tip` starts it): the thumb pushes on the rig mounted for
it, so the F/T wrench, the commands and the controller's state are all in ft_sensor_thumb; the
controller runs the thumb with its own gains without swinging (with gains sized from the
diagonal of its inertia it swung at 10-27 rad/s here), and tracks its estimate."""
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tacforce_ros import bagio, topics

sys.path.insert(0, str(Path(__file__).resolve().parent))
from graph_support import free_ports, unique_domain_id  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import executable, ros_env  # noqa: E402

pytestmark = pytest.mark.ros
SIM_SECONDS = 25.0       # the paper sequence's first command comes at 16 s
THUMB = slice(12, 16)


def test_the_thumb_closes_its_loop_on_its_own_rig(tmp_path):
    result = subprocess.run(
        [executable('session'), 'closed_loop', '--array', 'thumb_tip', '--out', str(tmp_path),
         '--sim-duration', str(SIM_SECONDS), '--duration', '240',
         '--ports', *[str(p) for p in free_ports(offset=2)]],
        env=ros_env(unique_domain_id(offset=77)), capture_output=True, text=True, timeout=300)
    logs = '\n'.join(p.read_text()[-800:] for p in sorted((tmp_path / 'logs').glob('*.log')))
    assert result.returncode == 0, result.stdout + result.stderr + logs
    bag = next(p for p in tmp_path.iterdir() if p.is_dir() and p.name != 'logs')
    frames = {}
    states, speeds = [], []
    for topic, _, msg in bagio.read_messages(bag, [topics.TOPIC_WRENCH, topics.TOPIC_DESIRED,
                                                   topics.TOPIC_CONTROLLER_STATE,
                                                   topics.TOPIC_JOINTS]):
        if topic == topics.TOPIC_JOINTS:
            speeds.append(np.abs(np.asarray(msg.velocity)[THUMB]).max())
            continue
        frames.setdefault(topic, set()).add(msg.header.frame_id)
        if topic == topics.TOPIC_CONTROLLER_STATE:
            states.append((msg.finger, msg.mode,
                           [msg.desired_force.x, msg.desired_force.y, msg.desired_force.z],
                           [msg.estimated_force.x, msg.estimated_force.y, msg.estimated_force.z]))
    assert frames == {t: {'ft_sensor_thumb'} for t in (
        topics.TOPIC_WRENCH, topics.TOPIC_DESIRED, topics.TOPIC_CONTROLLER_STATE)}
    assert {s[0] for s in states} == {'thumb'}
    commanded = [s for s in states if np.linalg.norm(s[2]) > 0]
    closed = [s for s in commanded if s[1] == 'closed_loop']
    # The loop runs closed but for a rare watchdog trip of a starved process (a joint stream
    # 24 ms late was seen with the machine busy), which the controller logs with its cause.
    assert len(commanded) > 300 and len(closed) >= 0.95 * len(commanded)
    log = (tmp_path / 'logs' / 'force_controller.log').read_text()
    # The guarded approach closes the thumb in, and force control takes over where it ends: at
    # the touch, or (a CI host at load 5 starved the estimator so) at q_d, the P term pressing;
    # the touch itself is tested in-process (test_control_approach.py).
    assert 'closed_loop: approaching q_d' in log, log
    ends = re.findall(r'closed_loop -> closed_loop: (touched|at q_d without a touch): ', log)
    assert len(ends) == 1, log
    trips = [(mode, cause) for mode, cause in re.findall(r'closed_loop -> (\w+): (.*)', log)
             if mode != 'closed_loop']
    watchdogs = ('joints stale', 'estimate stale', 'no valid estimate')  # estimator: stale
    assert all(mode in ('safe', 'hold') and cause.startswith(watchdogs)
               for mode, cause in trips), trips
    f_d, f_hat = np.array([s[2] for s in closed]), np.array([s[3] for s in closed])
    e_track = float(np.linalg.norm(f_d - f_hat, axis=1).mean())
    print(f'\nthumb: approach ended {ends[0]}, e_track {e_track:.3f} N over {len(closed)} '
          f'closed-loop ticks of '
          f'{len(commanded)} commanded, watchdog trips {trips}, fastest thumb joint '
          f'{max(speeds):.2f} rad/s')
    assert e_track < 0.1 and max(speeds) < 3.0
