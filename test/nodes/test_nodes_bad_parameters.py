"""Bad parameter values are refused at start-up with a message naming the parameter and why
(exit code EXIT_BAD_PARAMETERS), before any device is touched."""
import sys
from pathlib import Path

import pytest

from tacforce_ros.nodes.common import EXIT_BAD_PARAMETERS

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import executable, start, stop, unique_domain_id  # noqa: E402

pytestmark = pytest.mark.ros
DOMAIN = unique_domain_id(offset=61)

CASES = [
    ('estimator', ['stale_timeout:=-1.0'], 'stale_timeout: -1.0 is outside'),
    ('estimator', ['model_config:=/nonexistent/models.yaml'], 'model_config: /nonexistent'),
    ('estimator', ['realtime_priority:=99'], 'realtime_priority: 99 is outside'),
    ('allegro_driver', ['control_rate_hz:=500.0'], 'control_rate_hz: 500.0 is outside'),
    ('allegro_driver', ['force_controller.k_i:=[1.0, 2.0]'], 'k_i: expected 3 finite numbers'),
    ('allegro_driver', ["control:='torque'"], "control: 'torque' is not one of"),
    ('sim_world', ["scene:='no_such_scene'"], 'no_such_scene'),
    ('xela_driver', ["url:='http://127.0.0.1:5000'"], 'url: '),
    ('ft_bridge', ["force_unit:='furlong'"], "force_unit: 'furlong' is not one of"),
]


def test_bad_values_are_refused_with_a_clear_message():
    # All at once: start-up dominates, and each refusal is independent of the others.
    procs = [(name, message, start([executable(name), '--ros-args',
                                    *[a for p in params for a in ('-p', p)]], DOMAIN))
             for name, params, message in CASES]
    problems = []
    for name, message, proc in procs:
        try:
            code = proc.wait(timeout=60.0)
        finally:
            output = stop(proc)
        if code != EXIT_BAD_PARAMETERS or 'refusing to start' not in output \
                or message not in output:
            problems.append(f'{name} exited {code} without "{message}":\n{output[-600:]}')
    assert not problems, '\n'.join(problems)
