"""Bad parameter values are refused at start-up with a message naming the parameter and why
(exit code EXIT_BAD_PARAMETERS), before any device is touched."""
import sys
from pathlib import Path

import pytest

from tacforce_ros.nodes.runner import EXIT_BAD_PARAMETERS

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import executable, start, stop, unique_domain_id  # noqa: E402

pytestmark = pytest.mark.ros
DOMAIN = unique_domain_id(offset=61)

CASES = [
    ('estimator', ['stale_timeout:=-1.0'], 'stale_timeout: -1.0 is outside'),
    ('estimator', ['model_config:=/nonexistent/models.yaml'], 'model_config: /nonexistent'),
    ('estimator', ['realtime_priority:=99'], 'realtime_priority: 99 is outside'),
    ('estimator', ['lowpass_hz:=60.0'], 'lowpass_hz: low-pass cut-off 60 Hz must lie between'),
    ('estimator', ['lowpass_order:=0'], 'lowpass_order: 0 is outside'),
    ('allegro_driver', ['control_rate_hz:=500.0'], 'control_rate_hz: 500.0 is outside'),
    ('allegro_driver', ["control:='force'"], "control: 'force' is not one of"),
    ('force_controller', ['force_controller.k_i:=[1.0, 2.0]'], 'k_i: expected 3 finite numbers'),
    ('force_controller', ["estimate_array:='nose'"], "estimate_array: 'nose' is not an array"),
    ('force_controller', ["estimate_array:='ring_tip'"],
     'estimate_array: ring_tip is not on the controlled finger'),
    ('force_controller', ["estimate_array:='thumb_tip'", "force_controller.finger:='thumb'",
                          "force_controller.estimate_frame:='uskin_thumb_tip'"],
     "force_frame: 'ft_sensor' but the rig for the thumb is 'ft_sensor_thumb'"),
    ('sim_world', ["scene:='no_such_scene'"], 'no_such_scene'),
    ('xela_driver', ["url:='http://127.0.0.1:5000'"], 'url: '),
    ('ft_bridge', ["force_unit:='furlong'"], "force_unit: 'furlong' is not one of"),
    ('estimator', ["frame_prefix:='/left/'"], "frame_prefix: '/left/' is not a frame-id prefix"),
    ('grasp_controller', ['grasp.slip_margin:=1.5'], 'grasp.slip_margin: 1.5 must be in (0, 1]'),
    ('grasp_controller', ['force_controller.k_p:=[1.0]'], 'k_p: expected 4 finite numbers'),
    ('grasp_client', ["scene:='closed_loop_spherical'"],
     "scene: 'closed_loop_spherical' is a closed_loop scene, not a grasp"),
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


def test_a_model_file_with_nan_weights_is_refused_naming_the_entry(tmp_path):
    """Consistent checksums, NaN weights (a diverged training): the estimator refuses to start
    instead of publishing NaN forces flagged valid."""
    import json

    import numpy as np

    from tacforce_ros.estimation.model_io import _sha256
    from tacforce_ros.paths import config_dir
    with np.load(config_dir() / 'models' / 'index_tip_M3-lambda.npz', allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    header = json.loads(str(arrays.pop('header')))
    name = next(k for k in header['sha256'] if k.startswith('state.'))
    arrays[name] = np.full_like(arrays[name], np.nan, dtype=np.float64)
    header['sha256'][name] = _sha256(arrays[name])
    np.savez(tmp_path / 'nan.npz', header=np.array(json.dumps(header)), **arrays)
    (tmp_path / 'models.yaml').write_text('models:\n  index_tip: nan.npz\n')
    proc = start([executable('estimator'), '--ros-args', '-p',
                  f'model_config:={tmp_path / "models.yaml"}'], DOMAIN)
    try:
        code = proc.wait(timeout=60.0)
    finally:
        output = stop(proc)
    assert code == EXIT_BAD_PARAMETERS, output[-1000:]
    assert f"entry '{name}' holds" in output and 'NaN or Inf' in output, output[-1000:]
