"""The session plan (shared by the launch files and `session`): every executable and parameter
file it names exists, overrides are quoted so YAML cannot retype them, bad choices are refused."""
import ast
import dataclasses
import sys
from pathlib import Path

import pytest
import yaml

from tacforce_ros.bringup.session_plan import (MODES, PlanError, SessionArgs, params_node_key,
                                             plan, shipped_parameters)
from tacforce_ros.paths import share_dir

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import executable  # noqa: E402

LAUNCH = share_dir() / 'launch'


@pytest.mark.parametrize('mode', MODES)
@pytest.mark.parametrize('sim', [True, False])
def test_every_named_executable_and_file_exists(mode, sim):
    nodes = plan(SessionArgs(mode=mode, sim=sim))
    assert ('sim_world' in [n.executable for n in nodes]) == sim
    for node in nodes:
        assert executable(node.executable).is_file()
        for path in node.param_files:
            assert path.is_file(), f'{node.executable}: {path} missing'
            doc = yaml.safe_load(path.read_text())
            # Each file addresses this node in any namespace.
            assert list(doc) == [params_node_key(node.executable)], path
        # In simulation every node but the clock source runs on /clock.
        wants_sim_time = sim and node.executable != 'sim_world'
        assert node.overrides.get('use_sim_time', False) is wants_sim_time


@pytest.mark.parametrize('name, mode', [(mode, mode) for mode in MODES]
                         + [('two_hands_sim', 'two_hands')])
def test_launch_files_build_their_graph_from_the_plan(name, mode):
    path = LAUNCH / f'{name}.launch.py'
    tree = ast.parse(path.read_text())
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call)
             and getattr(n.func, 'id', '') == 'session_launch_description']
    assert [c.args[0].value for c in calls] == [mode]
    shared = ast.parse((LAUNCH / 'session_launch.py').read_text())
    imported = {alias.name for n in ast.walk(shared) if isinstance(n, ast.ImportFrom)
                and n.module == 'tacforce_ros.bringup.session_plan' for alias in n.names}
    assert 'plan' in imported


def test_string_overrides_survive_yaml():
    node = next(n for n in plan(SessionArgs(mode='calibration'))
                if n.executable == 'allegro_driver')
    args = node.ros_args()
    value = args[args.index('control:=\'off\'')].split(':=', 1)[1]
    assert yaml.safe_load(value) == 'off'      # bare off would read as False


@pytest.mark.parametrize('field, value, message', [
    ('mode', 'teleop', 'mode'), ('hand_side', 'middle', 'hand_side'),
    ('frame_prefix', '/left/', 'frame_prefix: .* is not a frame-id prefix')])
def test_bad_choices_are_refused(field, value, message):
    args = {'mode': 'calibration', field: value}
    with pytest.raises(PlanError, match=message):
        plan(SessionArgs(**args))


def test_the_closed_loop_array_picks_the_scene_the_finger_and_the_estimate():
    nodes = {n.executable: n for n in plan(SessionArgs('closed_loop', array='middle_tip'))}
    assert nodes['sim_world'].overrides['scene'] == 'closed_loop_middle_tip_spherical'
    controller = nodes['force_controller'].overrides
    assert (controller['estimate_array'], controller['force_controller.finger'],
            controller['force_controller.estimate_frame']) == ('middle_tip', 'middle',
                                                               'uskin_middle_tip')
    assert nodes['sync_recorder'].overrides['array'] == 'middle_tip'
    assert 'frame_id' not in nodes['ft_bridge'].overrides          # the rig of the fingers


def test_the_thumb_closes_its_loop_on_the_rig_mounted_for_it_with_its_own_gains():
    from tacforce_ros.control.force_controller import finger_params_file
    nodes = {n.executable: n for n in plan(SessionArgs('closed_loop', array='thumb_tip'))}
    assert nodes['sim_world'].overrides['scene'] == 'closed_loop_thumb_tip_spherical'
    controller = nodes['force_controller']
    assert controller.param_files[-1] == finger_params_file('thumb')
    assert (controller.overrides['force_controller.finger'],
            controller.overrides['force_controller.force_frame']) == ('thumb', 'ft_sensor_thumb')
    assert nodes['ft_bridge'].overrides['frame_id'] == 'ft_sensor_thumb'
    assert nodes['command_player'].overrides['frame_id'] == 'ft_sensor_thumb'


@pytest.mark.parametrize('array, message', [
    ('index_middle', 'not a fingertip array'), ('pinky_tip', 'not an array of the right hand')])
def test_a_closed_loop_array_the_controller_cannot_drive_is_refused(array, message):
    with pytest.raises(PlanError, match=message):
        plan(SessionArgs('closed_loop', array=array))


def test_a_closed_loop_array_without_a_model_is_refused(tmp_path):
    models = tmp_path / 'models.yaml'
    models.write_text('models: {index_tip: index_tip_M3-lambda.npz}\n')
    with pytest.raises(PlanError, match='has no model for ring_tip'):
        plan(SessionArgs('closed_loop', array='ring_tip', model_config=str(models)))


def test_a_side_without_a_description_is_refused(monkeypatch, tmp_path):
    from tacforce_ros.bringup import session_plan
    monkeypatch.setattr(session_plan, 'hand_config', lambda side: tmp_path / f'{side}.yaml')
    with pytest.raises(PlanError, match='no hand description'):
        plan(SessionArgs(mode='calibration', hand_side='left'))


def test_the_left_hand_gives_every_node_its_description_and_a_frame_prefix_its_nodes():
    from tacforce_ros.hand.description import hand_config
    nodes = plan(SessionArgs(mode='closed_loop', hand_side='left', frame_prefix='left/'))
    described = {n.executable: n.overrides['hand_config'] for n in nodes
                 if 'hand_config' in n.overrides}
    assert set(described) == {'sim_world', 'xela_driver', 'estimator', 'allegro_driver',
                              'force_controller', 'sync_recorder'}
    assert set(described.values()) == {str(hand_config('left'))}
    prefixed = {n.executable for n in nodes if n.overrides.get('frame_prefix') == 'left/'}
    assert prefixed == {'sim_world', 'xela_driver', 'ft_bridge', 'estimator',
                        'force_controller', 'command_player'}
    # No prefix asked: none passed (the nodes' own default is empty).
    assert not any('frame_prefix' in n.overrides for n in plan(SessionArgs(mode='closed_loop')))


def test_seed_reaches_the_simulator_and_the_session_metadata():
    nodes = {n.executable: n for n in plan(SessionArgs(mode='closed_loop', seed=11))}
    assert nodes['sim_world'].overrides['seed'] == 11
    recorder = nodes['sync_recorder'].overrides
    assert (recorder['seed'], recorder['scene']) == (11, 'closed_loop_spherical')
    hardware = {n.executable: n for n in plan(SessionArgs(mode='closed_loop', sim=False))}
    assert 'seed' not in hardware['sync_recorder'].overrides


def test_negative_seed_other_than_the_scene_default_is_refused():
    with pytest.raises(PlanError, match='seed'):
        plan(SessionArgs(mode='closed_loop', seed=-2))


def test_boolean_launch_arguments_are_read_as_launch_reads_them_and_others_refused():
    from tacforce_ros.bringup.session_plan import launch_bool
    assert [launch_bool('sim', v) for v in ('true', 'True', '1', 'false', 'FALSE', '0')] == [
        True, True, True, False, False, False]
    for text in ('yes', '', 'ture', '2'):
        with pytest.raises(PlanError, match=f"sim:={text!r}: expected true or false"):
            launch_bool('sim', text)


def test_a_missing_or_mismatched_scene_is_refused_before_any_node_starts():
    with pytest.raises(PlanError, match='scene: .*nosuchplate'):
        plan(SessionArgs(mode='closed_loop', plate='nosuchplate'))
    with pytest.raises(PlanError, match='is a calibration scene, not closed_loop'):
        plan(SessionArgs(mode='closed_loop', scene='calibration_index_tip_flat'))
    assert plan(SessionArgs(mode='closed_loop', sim=False, plate='nosuchplate'))  # no scene


def test_a_chosen_sequence_reaches_the_command_player_and_a_missing_one_is_refused():
    nodes = {n.executable: n for n in plan(SessionArgs(mode='closed_loop'))}
    assert 'sequence' not in nodes['command_player'].overrides      # the params file's
    nodes = {n.executable: n for n in plan(SessionArgs(mode='closed_loop',
                                                       sequence='fault_drill'))}
    assert nodes['command_player'].overrides['sequence'] == 'fault_drill'
    with pytest.raises(PlanError, match='sequence: no_such_drill: no such file'):
        plan(SessionArgs(mode='closed_loop', sequence='no_such_drill'))


def test_lockstep_and_scene_length_reach_the_simulator():
    nodes = {n.executable: n for n in plan(SessionArgs(mode='closed_loop'))}
    assert nodes['sim_world'].overrides['lockstep'] is True        # the default
    assert nodes['sim_world'].overrides['stop_after'] == 0.0
    nodes = {n.executable: n for n in plan(SessionArgs(mode='calibration', lockstep=False,
                                                       sim_duration=40.0))}
    assert nodes['sim_world'].overrides['lockstep'] is False
    assert nodes['sim_world'].overrides['stop_after'] == 40.0
    with pytest.raises(PlanError, match='sim_duration'):
        plan(SessionArgs(mode='closed_loop', sim_duration=-1.0))


def test_session_sees_the_end_of_the_scene_in_the_log_of_sim_world(tmp_path):
    from tacforce_ros.bringup.session_plan import SCENE_DONE_MARKER
    from tacforce_ros.tools.session import SceneLog
    log = SceneLog(tmp_path / 'sim_world.log')
    assert not log.done()                                  # no log yet
    head, tail = SCENE_DONE_MARKER[:4], SCENE_DONE_MARKER[4:]
    with open(tmp_path / 'sim_world.log', 'w') as out:
        out.write('[INFO] [sim_world]: servos on\n[INFO] [sim_world]: ' + head)
        out.flush()
        assert not log.done()
        out.write(tail + ' 80.0 s simulated\n')             # the marker across two reads
        out.flush()
        assert log.done()


def test_each_session_tares_into_a_file_of_its_own_outside_the_bags(tmp_path, monkeypatch):
    """A restarted estimator loads its session's tare; another session never does."""
    monkeypatch.setenv('ROS_HOME', str(tmp_path / 'ros'))
    first = {n.executable: n for n in plan(SessionArgs(mode='closed_loop', out=str(tmp_path)))}
    second = {n.executable: n for n in plan(SessionArgs(mode='closed_loop', out=str(tmp_path),
                                                        session_id='b'))}
    tare = Path(first['estimator'].overrides['tare_file'])
    assert tare.parent == tmp_path / 'ros' / 'tacforce_ros'
    assert second['estimator'].overrides['tare_file'] != str(tare)


def test_a_crash_drill_of_a_node_the_session_lacks_is_refused_before_any_start(tmp_path):
    import subprocess
    done = subprocess.run([str(executable('session')), 'calibration',
                           '--out', str(tmp_path), '--crash', 'estimator', '10', '2'],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "'estimator' is not a node of this session" in done.stderr
    assert not (tmp_path / 'logs').exists()


def test_a_namespace_reaches_every_node_with_its_own_clock_in_simulation():
    for compose in (False, True):
        nodes = plan(SessionArgs(mode='closed_loop', namespace='/left', compose=compose))
        parts = [p for n in nodes for p in (n.parts or (n,))]
        assert {p.namespace for p in parts} == {'/left'}
        for part in parts:
            args = part.ros_args()
            assert ['-r', '__ns:=/left', '-r', '/clock:=/left/clock'] == args[1:5], args
    hardware = plan(SessionArgs(mode='closed_loop', sim=False, namespace='/rig2'))
    assert all(n.remappings == () and n.namespace == '/rig2' for n in hardware)
    assert all(n.namespace == '' and '-r' not in n.ros_args()
               for n in plan(SessionArgs(mode='closed_loop')))


@pytest.mark.parametrize('namespace', ['left', '/left/', '/2hands', '/le ft'])
def test_a_namespace_that_is_not_one_is_refused(namespace):
    with pytest.raises(PlanError, match='namespace'):
        plan(SessionArgs(mode='calibration', namespace=namespace))


def test_the_two_hands_launch_takes_what_both_hands_share_and_nothing_set_per_hand():
    """two_hands_sim.launch.py declares only the arguments session_plan.two_hands shares (out
    among them); what it sets per hand is not among them, and is refused when given."""
    from tacforce_ros.bringup.session_plan import ARGUMENT_NAMES, PER_HAND
    tree = ast.parse((LAUNCH / 'session_launch.py').read_text())
    shared = next(ast.literal_eval(n.value) for n in ast.walk(tree) if isinstance(n, ast.Assign)
                  and getattr(n.targets[0], 'id', '') == 'TWO_HANDS')
    assert 'out' in shared
    assert not {ARGUMENT_NAMES.get(name, name) for name in PER_HAND} & set(shared)


def test_two_hands_planned_together_keep_their_own_tare():
    left, right = (plan(SessionArgs(mode='closed_loop', namespace=ns, session_id='same'))
                   for ns in ('/left', '/right'))
    tare = [next(n for n in nodes if n.executable == 'estimator').overrides['tare_file']
            for nodes in (left, right)]
    assert tare[0] != tare[1]


@pytest.mark.parametrize('sim', [True, False])
def test_the_recorder_starts_before_the_streams_it_records(sim):
    names = [n.executable for n in plan(SessionArgs(mode='closed_loop', sim=sim))]
    assert names.index('sync_recorder') == (1 if sim else 0), names
    assert names[0] == ('sim_world' if sim else 'sync_recorder')


def test_a_campaign_session_is_the_first_due_slot_and_only_for_calibration(tmp_path):
    from tacforce_ros.bringup.session_plan import campaign_session
    from tacforce_ros.recording.campaign import Campaign, CampaignPlan
    folder = tmp_path / 'campaign'
    Campaign.create(folder, CampaignPlan(hand_side='right', arrays=('palm_center', 'thumb_tip'),
                                         plates=('convex',), sessions=2, seconds=30.0))
    args = campaign_session(SessionArgs('calibration', campaign=str(folder)))
    assert (args.array, args.plate, args.out, args.sim_duration) == (
        'palm_center', 'convex', str(folder), 30.0)
    nodes = {n.executable: n for n in plan(args)}
    assert nodes['sim_world'].overrides['scene'] == 'calibration_palm_center_convex'
    assert nodes['coverage_view'].overrides['campaign'] == str(folder)
    hardware = campaign_session(SessionArgs('calibration', sim=False, campaign=str(folder)))
    assert hardware.sim_duration == 0.0 and 'session_seconds' not in {
        n.executable: n for n in plan(hardware)}['coverage_view'].overrides
    with pytest.raises(PlanError, match='records calibration sessions'):
        campaign_session(SessionArgs('closed_loop', campaign=str(folder)))
    with pytest.raises(PlanError, match='not a campaign'):
        campaign_session(SessionArgs('calibration', campaign=str(tmp_path)))


def test_a_campaign_session_after_a_poor_one_takes_the_next_seed_and_a_complete_one_none(
        tmp_path):
    import json
    from tacforce_ros.hand.description import load_hand
    from tacforce_ros.bringup.session_plan import campaign_session
    from tacforce_ros.recording.campaign import Campaign, CampaignPlan, CoverageLimits
    from tacforce_ros.recording.sim_session import record_session
    from tacforce_ros.sim.scene import session_seed
    folder = tmp_path / 'campaign'
    Campaign.create(folder, CampaignPlan(
        hand_side='right', arrays=('index_tip',), plates=('flat',), sessions=1, seconds=6.0,
        seed=2, limits=CoverageLimits(min_peak_force=0.0, min_shear_sectors=0, min_rests=0)))
    (folder / 'rejected').mkdir()
    (folder / 'rejected' / 'x.verdict.json').write_text(json.dumps(
        {'array': 'index_tip', 'plate': 'flat'}))
    args = campaign_session(SessionArgs('calibration', campaign=str(folder)))
    assert args.seed == session_seed(2, 'index_tip', 'flat', 1)

    class Silent:
        def update(self, n):
            pass
    record_session(folder / 'index_tip_flat_s0', load_hand(), 'index_tip', 'flat', 0, 6.0, 2,
                   Silent())
    with pytest.raises(PlanError, match='is complete, nothing is due'):
        campaign_session(SessionArgs('calibration', campaign=str(folder)))


@pytest.mark.parametrize('args, message', [
    (dict(mode='calibration', array='palm_nosuch'),
     "array: 'palm_nosuch' is not an array of the right hand"),
    (dict(mode='calibration', sim=False, array='palm_nosuch'), 'array: .* not an array'),
    (dict(mode='calibration', model_config='m.yaml'), 'model: only a closed_loop or grasp session'),
    (dict(mode='calibration', sequence='fault_drill'), 'sequence: only a closed_loop session'),
    (dict(mode='closed_loop', campaign='somewhere'), 'campaign: only a calibration session'),
    (dict(mode='calibration', sim=False, seed=4), 'seed: only simulation reads it'),
    (dict(mode='closed_loop', sim=False, real_time_factor=2.0, lockstep=False),
     'real_time_factor, lockstep: only simulation reads them'),
    (dict(mode='calibration', plate='Flat plate'), "plate: 'Flat plate' is not a plate name"),
    (dict(mode='calibration', real_time_factor=0.0), 'real_time_factor: 0.0 must be above 0'),
    (dict(mode='calibration', can_port=70000), 'can_port: 70000 is not a port'),
    (dict(mode='calibration', xela_port=6000, netft_port=6000), 'must differ'),
    (dict(mode='closed_loop', grip=2.0), 'grip: only a grasp session reads it'),
    (dict(mode='calibration', grasp_object='tennis_ball'), 'object: only a grasp session'),
    (dict(mode='grasp', sim=False, grip=2.0), 'grip: only simulation reads it'),
    (dict(mode='grasp', grasp_object='Egg'), "object: 'Egg' is not an object name"),
    (dict(mode='grasp', grasp_object='egg'), 'scene: .*grasp_egg'),
    (dict(mode='grasp', scene='closed_loop_spherical'),
     "scene 'closed_loop_spherical' is a closed_loop scene, not grasp"),
    (dict(mode='grasp', grip=0.2), 'the grip must be at least 0.3 N'),
    (dict(mode='grasp', grip=50.0),
     r"grip 50 N: at most 2\.\d\d N at scene 'grasp_golf_ball'\'s start pose"),
    (dict(mode='grasp', grasp_object='tennis_ball', grip=2.5),
     r"grip 2\.5 N: at most 2\.\d\d N at scene 'grasp_tennis_ball'")])
def test_an_argument_the_session_would_ignore_or_cannot_use_is_refused(args, message):
    """In both modes, simulated or not: what the session would silently ignore (another mode's,
    or simulation's, on the hardware) or could not use is refused before any node starts."""
    with pytest.raises(PlanError, match=message):
        plan(SessionArgs(**args))


def test_numeric_launch_arguments_name_themselves_when_unreadable():
    from tacforce_ros.bringup.session_plan import launch_number
    assert launch_number('seed', ' 7 ', int) == 7 and launch_number('sim_duration', '2.5') == 2.5
    with pytest.raises(PlanError, match="seed:='7.5': expected an integer"):
        launch_number('seed', '7.5', int)
    with pytest.raises(PlanError, match="real_time_factor:='fast': expected a number"):
        launch_number('real_time_factor', 'fast')


def test_two_hands_share_the_arguments_and_keep_their_own_names_ports_and_bags():
    from tacforce_ros.bringup.session_plan import two_hands
    hands = two_hands(SessionArgs('closed_loop', out='runs/today', seed=5, array='middle_tip'))
    assert [(h.hand_side, h.namespace, h.frame_prefix, h.out, h.seed, h.array) for h in hands] == [
        ('right', '/right', 'right/', 'runs/today/right', 5, 'middle_tip'),
        ('left', '/left', 'left/', 'runs/today/left', 5, 'middle_tip')]
    ports = [p for h in hands for p in (h.xela_port, h.netft_port, h.can_port)]
    assert len(set(ports)) == 6
    for hand in hands:
        recorder = next(n for n in plan(hand) if n.executable == 'sync_recorder')
        assert recorder.overrides['output_dir'] == hand.out
        assert recorder.namespace == hand.namespace


@pytest.mark.parametrize('field, value, name', [
    ('hand_side', 'left', 'hand_side'), ('namespace', '/x', 'namespace'),
    ('can_port', 1234, 'can_port'), ('model_config', 'm.yaml', 'model')])
def test_two_hands_refuse_what_they_set_per_hand(field, value, name):
    from tacforce_ros.bringup.session_plan import two_hands
    with pytest.raises(PlanError, match=f'{name}: set per hand'):
        two_hands(SessionArgs('closed_loop', **{field: value}))
    with pytest.raises(PlanError, match='simulated closed-loop session only'):
        two_hands(SessionArgs('calibration'))


def test_a_grasp_session_holds_the_scene_object_with_the_scene_mount_and_goal():
    """Simulation: no F/T bridge (a grasp has no F/T sensor), the hand driver and the grasp
    controller mounted as the scene's hand (its gravity), and a client that sends the scene's
    goal at its goal_at and whose clean end is the session's; on the hardware, no client (the
    user sends goals) and no simulator."""
    from tacforce_ros.sim import load_scene
    nodes = {n.executable: n for n in plan(SessionArgs(mode='grasp', grasp_object='tennis_ball',
                                                       grip=2.0, hold_time=3.0))}
    scene = load_scene('grasp_tennis_ball')
    assert list(nodes) == ['sim_world', 'sync_recorder', 'xela_driver', 'estimator',
                           'allegro_driver', 'grasp_controller', 'grasp_client']
    assert nodes['sim_world'].overrides['scene'] == 'grasp_tennis_ball'
    gravity = [float(v) for v in scene.grasp['gravity']]
    assert nodes['allegro_driver'].overrides['gravity'] == gravity
    assert nodes['grasp_controller'].overrides['gravity'] == gravity
    client = nodes['grasp_client']
    assert client.finishes and not any(n.finishes for n in nodes.values() if n is not client)
    assert client.overrides['start_time'] == scene.grasp['goal_at']
    assert (client.overrides['grip_force'], client.overrides['hold_time']) == (2.0, 3.0)
    assert client.overrides['fingers'] == ['thumb', 'index']
    assert nodes['sync_recorder'].overrides['plate'] == 'tennis_ball'
    hardware = [n.executable for n in plan(SessionArgs(mode='grasp', sim=False))]
    assert hardware == ['sync_recorder', 'xela_driver', 'estimator', 'allegro_driver',
                        'grasp_controller']
    composed = plan(SessionArgs(mode='grasp', compose=True))
    assert [n.executable for n in composed] == ['sim_world', 'grasp_client',
                                                'tacforce_container']


def test_a_grasp_session_refuses_models_without_the_thumbs_fingertip(tmp_path):
    models = tmp_path / 'models.yaml'
    models.write_text('models:\n  index_tip: index_tip_M3-lambda.npz\n')
    with pytest.raises(PlanError, match="model: .* a grasp needs the thumb's fingertip"):
        plan(SessionArgs(mode='grasp', model_config=str(models)))


def test_a_namespaced_grasp_client_finds_the_server_of_its_own_hand():
    """The client's action name is relative (shipped file and default), so in /left it is
    /left/grasp_controller/grasp, where that hand's grasp_controller serves (~/grasp)."""
    nodes = {n.executable: n for n in plan(SessionArgs(mode='grasp', namespace='/left'))}
    client = nodes['grasp_client']
    assert client.namespace == '/left' and nodes['grasp_controller'].namespace == '/left'
    assert 'action' not in client.overrides
    shipped = shipped_parameters('grasp_client')['action']
    assert not shipped.startswith('/') and shipped == 'grasp_controller/grasp'


def test_the_grip_bound_is_the_controller_s_own_check_at_the_scene_s_pose():
    """The plan's upper bound is where GraspController.check starts refusing a goal at the
    scene's start pose: just below it a goal passes the check, just above it is refused."""
    import numpy as np
    from tacforce_ros.control.force_controller import ForceControllerConfig
    from tacforce_ros.control.grasp import (GraspConfig, GraspController, GraspGoal,
                                            GraspGoalError, finger_configs, scene_grip_top)
    from tacforce_ros.hand.description import load_hand
    from tacforce_ros.hand.kinematics import HandKinematics
    from tacforce_ros.hand.pinch import pad
    from tacforce_ros.sim import load_scene
    from tacforce_ros.sim.operator import FINGER_JOINTS
    hand = load_hand()
    scene = load_scene('grasp_golf_ball')
    top = scene_grip_top(scene, hand, ForceControllerConfig())
    assert GraspConfig.grip_min < top < 5.0
    plan(SessionArgs('grasp', grip=round(top - 0.01, 2)))          # below it: planned
    gravity = tuple(scene.grasp['gravity'])
    kinematics = HandKinematics.for_hand(hand, gravity=gravity)
    fingers = tuple(scene.grasp['fingers'])
    controller = GraspController(finger_configs(ForceControllerConfig(), hand, fingers),
                                 kinematics, lambda q, f: pad(hand, kinematics, q, f)[0],
                                 GraspConfig(gravity=gravity))
    q16 = np.asarray(scene.grasp['hand_pose'], np.float64).copy()
    targets = {}
    for finger, pose in scene.grasp['fingers'].items():
        q16[FINGER_JOINTS[finger]] = pose['pose']
        targets[finger] = tuple(pose['contact_pose'])
    goal = GraspGoal(fingers=fingers, grip=top - 0.01, targets=targets,
                     mass=scene.grasp_object.mass)
    controller.check(goal, q16)
    with pytest.raises(GraspGoalError, match='outside the safe range'):
        controller.check(dataclasses.replace(goal, grip=top + 0.01), q16)
