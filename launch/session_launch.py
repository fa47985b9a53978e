"""Shared body of calibration.launch.py, closed_loop.launch.py, grasp.launch.py and
two_hands_sim.launch.py (needs a full ROS 2 install with the launch and launch_ros packages; on
this machine `session <mode>` starts the same graph).

The node list, parameter files and overrides come from tacforce_ros.bringup.session_plan, the
same source the `session` tool reads, and so do the checks of every argument: a bad argument
ends the launch before any process starts, naming the argument (launch prints "Caught exception
in launch", exit code 1). A node that exits with an error while the session runs, or does not
stop cleanly when it is shut down, ends the launch with exit code 1, naming the node; a clean
shutdown (Ctrl-C, the end of the scene, a simulated grasp's client ending with its result) exits 0.
robot_state_publisher publishes the package URDF on /tf for RViz; our nodes compute frames from
the URDF in-process and do not need /tf.
"""
import signal

from launch import LaunchDescription
from launch.actions import (DeclareLaunchArgument, LogInfo, OpaqueFunction, RegisterEventHandler,
                            Shutdown)
from launch.event_handlers import OnProcessExit, OnProcessIO
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from tacforce_ros.hand.description import hand_config, load_hand
from tacforce_ros.bringup.session_plan import (CAN_PORT, NETFT_PORT, SCENE_DONE_MARKER, XELA_PORT,
                                             PlanError, SessionArgs, campaign_session, launch_bool,
                                             launch_number, plan, two_hands)

COMMON = {
    'sim': ('true', 'true: sim_world and its device emulators; false: the hardware'),
    'hand_side': ('right', 'right or left: the hand description '
                  'config/hand/allegro_<side>_uskin.yaml (and its models)'),
    'array': ('index_tip', 'array pressed on the plate (calibration) or controlled'),
    'plate': ('spherical', 'push-plate (calibration) or object (closed loop)'),
    'scene': ('', 'sim scene; empty: derived from the mode, array and plate'),
    'out': ('bags', 'folder for the recorded bags'),
    'real_time_factor': ('1.0', 'simulated seconds per wall second (sim only; with lockstep '
                         'the most it runs at)'),
    'lockstep': ('true', 'sim only: simulated time waits for the nodes closing the loop; '
                 'false: free-running'),
    'sim_duration': ('0.0', 'sim only: shut down after this many simulated seconds; 0: run '
                     'until stopped'),
    'seed': ('-1', 'simulator seed (sim only); -1: the scene\'s own'),
    'compose': ('false', 'true: every node but the simulator in one tacforce_container process'),
    'namespace': ('', 'every node in this namespace (e.g. /left; in simulation its /clock too); '
                  'empty: the root namespace'),
    'frame_prefix': ('', 'put in front of every frame id (e.g. left/), also in '
                     'robot_state_publisher\'s TF; empty: the URDF\'s names'),
    'xela_port': (str(XELA_PORT), 'sim only: the simulated xela_server\'s port (another per '
                  'hand)'),
    'netft_port': (str(NETFT_PORT), 'sim only: the simulated Net F/T box\'s UDP port'),
    'can_port': (str(CAN_PORT), 'sim only: the simulated hand\'s socketcand port'),
    'autostart': ('true', 'the lifecycle drivers (xela_driver, ft_bridge, allegro_driver) '
                  'configure and activate themselves; false: they start unconfigured, for '
                  'ros2 lifecycle set or a lifecycle manager'),
}
ONLY = {
    'calibration': {
        'campaign': ('', 'record the next session this campaign folder has due (its array, '
                     'plate and folder; in simulation its length and seed)'),
    },
    'grasp': {
        'model': ('', 'estimator models YAML, with the thumb\'s fingertip and another; empty: '
                  'config/models/default.yaml'),
        'object': ('golf_ball', 'sim: the object held, scene grasp_<object> (golf_ball, '
                   'gelatin_box, marker, tennis_ball, foam_brick)'),
        'grip': ('1.0', 'grip force (N)'),
        'hold_time': ('0.0', 'sim: hold this long, then release and end; 0: until the scene '
                      'ends or Ctrl-C'),
    },
    'closed_loop': {
        'model': ('', 'estimator models YAML; empty: config/models/default.yaml (the left hand: '
                  'config/models/left/default.yaml)'),
        'sequence': ('', 'force command sequence, a name in config/commands/ or a path; empty: '
                     'paper_70s'),
    },
}
# two_hands_sim: what both hands share (the rest is set per hand, session_plan.two_hands).
TWO_HANDS = ('array', 'plate', 'out', 'real_time_factor', 'lockstep', 'sim_duration', 'seed',
             'compose', 'autostart', 'sequence')


def arguments(mode: str) -> dict[str, tuple[str, str]]:
    """The launch arguments of a mode: name -> (default, description)."""
    if mode == 'two_hands':
        every = {**COMMON, **ONLY['closed_loop']}
        return {name: every[name] for name in TWO_HANDS}
    return {**COMMON, **ONLY[mode]}


def session_args(mode: str, value: dict[str, str]) -> SessionArgs:
    """SessionArgs from the launch arguments' text; PlanError names a value it cannot read."""
    text = {**{name: default for name, (default, _) in COMMON.items()},
            **{name: default for only in ONLY.values() for name, (default, _) in only.items()},
            **value}
    grasp = ({'grasp_object': text['object'], 'grip': launch_number('grip', text['grip']),
              'hold_time': launch_number('hold_time', text['hold_time'])}
             if mode == 'grasp' else {})
    return SessionArgs(
        mode='closed_loop' if mode == 'two_hands' else mode, sim=launch_bool('sim', text['sim']),
        hand_side=text['hand_side'], array=text['array'], plate=text['plate'],
        scene=text['scene'], model_config=text['model'], sequence=text['sequence'],
        out=text['out'], campaign=text['campaign'],
        real_time_factor=launch_number('real_time_factor', text['real_time_factor']),
        lockstep=launch_bool('lockstep', text['lockstep']),
        sim_duration=launch_number('sim_duration', text['sim_duration']),
        seed=launch_number('seed', text['seed'], int),
        compose=launch_bool('compose', text['compose']),
        autostart=launch_bool('autostart', text['autostart']),
        namespace=text['namespace'], frame_prefix=text['frame_prefix'],
        xela_port=launch_number('xela_port', text['xela_port'], int),
        netft_port=launch_number('netft_port', text['netft_port'], int),
        can_port=launch_number('can_port', text['can_port'], int), **grasp)


def _actions(context, mode: str):
    """Every process of the session, after every argument was checked (nothing starts before)."""
    declared = arguments(mode)
    try:
        # Another session file's argument, given here, would be ignored: refused by name. (Other
        # names may be a including launch file's own, and are left alone.)
        ours = set(COMMON).union(*ONLY.values())
        foreign = sorted(set(context.launch_configurations) & ours - set(declared))
        if foreign:
            raise PlanError(f'{", ".join(foreign)}: not an argument of this launch file (it '
                            f'takes {", ".join(declared)})'
                            + ('; two_hands_sim sets hand, namespace, frame prefix, ports and '
                               'models per hand' if mode == 'two_hands' else ''))
        args = session_args(mode, {name: LaunchConfiguration(name).perform(context)
                                   for name in declared})
        sessions = two_hands(args) if mode == 'two_hands' else [args]
        sessions = [campaign_session(a) if a.campaign else a for a in sessions]
        plans = [(a, plan(a)) for a in sessions]
    except PlanError as exc:
        raise PlanError(f'{mode}: {exc}') from None
    return [action for a, nodes in plans for action in _session_actions(a, nodes)]


def _session_actions(args: SessionArgs, nodes):
    # All nodes start together (as in `session`): the hand driver waits for the first /clock,
    # which sim_world publishes once its emulators listen (on hardware: up to connect_timeout
    # for the hand), the XELA and F/T clients keep trying their devices, and the command player
    # starts its sequence only when the controller and the recorder listen.
    actions = []
    for node in nodes:
        action = (Node(package='tacforce_ros', executable=node.executable, output='screen',
                       arguments=node.command_args()) if node.parts else
                  Node(package='tacforce_ros', executable=node.executable, output='screen',
                       namespace=node.namespace or None, remappings=list(node.remappings),
                       parameters=[str(p) for p in node.param_files] + [node.overrides]))
        actions.append(action)
        # A node that exits with an error ends the launch with exit code 1, naming itself.
        actions.append(RegisterEventHandler(OnProcessExit(
            target_action=action, on_exit=_fail_on_error(node.namespace, node.executable))))
        if node.finishes:
            # A client's clean end (a simulated grasp's result) ends the session.
            actions.append(RegisterEventHandler(OnProcessExit(
                target_action=action, on_exit=_shutdown_when_finished(node.executable))))
        if node.executable == 'sim_world':
            # The end of the scene (sim_duration): shut down, the drivers before the emulators.
            actions.append(RegisterEventHandler(OnProcessIO(
                target_action=action, on_stdout=_shutdown_when_done,
                on_stderr=_shutdown_when_done)))
    if not _installed('robot_state_publisher'):
        # Checked here, before anything starts: launch ends on a package it cannot find, and
        # leaves the processes it already started running.
        actions.append(LogInfo(msg='robot_state_publisher is not installed: no /tf of the hand '
                               'for RViz (the session\'s nodes do not need it)'))
        return actions
    urdf = load_hand(hand_config(args.hand_side)).urdf_path    # plan() checked it exists
    actions.append(Node(package='robot_state_publisher', executable='robot_state_publisher',
                        namespace=args.namespace or None,
                        remappings=[('/clock', f'{args.namespace}/clock')]
                        if args.namespace and args.sim else [],
                        parameters=[{'robot_description': urdf.read_text(),
                                     'frame_prefix': args.frame_prefix,
                                     'use_sim_time': args.sim}]))
    return actions


def _installed(package: str) -> bool:
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix
    try:
        get_package_prefix(package)
    except PackageNotFoundError:
        return False
    return True


class NodeFailed(RuntimeError):
    """A node of the session exited with an error: launch ends with exit code 1."""


# Exit codes of a node stopped by the shutdown: 0, or the stop signal itself when it came while
# Python was still starting; 255 is launch's word for a child whose end it did not see.
STOPPED = (0, -signal.SIGINT, -signal.SIGTERM, 255)


def _fail_on_error(namespace: str, name: str):
    def handler(event, context):
        # launch sets no exit code for Shutdown; an exception in a handler it reports and ends
        # on with exit code 1. While shutting down, a node that could not stop cleanly (its
        # device not left safe: exit code 1; killed by launch's escalation) fails it too.
        stopped = STOPPED if context.is_shutdown else (0,)
        if event.returncode is not None and event.returncode not in stopped:
            raise NodeFailed(f'{namespace}/{name} exited with code {event.returncode}; its log '
                             'is above')
        return None
    return handler


def _shutdown_when_finished(name: str):
    def handler(event, context):
        if event.returncode == 0 and not context.is_shutdown:
            return [Shutdown(reason=f'{name} finished')]
        return None
    return handler


def _shutdown_when_done(event):
    if SCENE_DONE_MARKER.encode() in event.text:
        return [Shutdown(reason='the scene ended (sim_duration)')]
    return None


def session_launch_description(mode: str) -> LaunchDescription:
    """calibration, closed_loop, grasp, or two_hands (two simulated closed-loop hands)."""
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=text)
         for name, (default, text) in arguments(mode).items()]
        + [OpaqueFunction(function=_actions, args=[mode])])
