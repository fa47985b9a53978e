"""Shared body of calibration.launch.py and closed_loop.launch.py (needs a full ROS 2 install with
the launch and launch_ros packages; on this machine `session <mode>` starts the same graph).

The node list, parameter files and overrides come from tacforce_ros.nodes.session_plan, the
same source the `session` tool reads. robot_state_publisher publishes the package URDF on /tf
for RViz; our nodes compute frames from the URDF in-process and do not need /tf.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction, RegisterEventHandler, Shutdown
from launch.event_handlers import OnProcessExit, OnProcessIO
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from tacforce_ros.hand.description import hand_config, load_hand
from tacforce_ros.nodes.session_plan import (CAN_PORT, NETFT_PORT, SCENE_DONE_MARKER, XELA_PORT,
                                             SessionArgs, campaign_session, launch_bool,
                                             plan)

ARGUMENTS = {
    'sim': ('true', 'true: sim_world and its device emulators; false: the hardware'),
    'hand_side': ('right', 'right or left: the hand description '
                  'config/hand/allegro_<side>_uskin.yaml (and its models)'),
    'array': ('index_tip', 'array pressed on the plate (calibration) or controlled'),
    'plate': ('spherical', 'push-plate (calibration) or object (closed loop)'),
    'scene': ('', 'sim scene; empty: derived from the mode, array and plate'),
    'model': ('', 'estimator models YAML; empty: config/models/default.yaml (the left hand: '
              'config/models/left/default.yaml)'),
    'sequence': ('', 'closed loop: force command sequence, a name in config/commands/ or a '
                 'path; empty: paper_70s'),
    'out': ('bags', 'folder for the recorded bags'),
    'campaign': ('', 'calibration: record the next session this campaign folder has due (its '
                 'array, plate and folder; in simulation its length and seed)'),
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
    'xela_port': (str(XELA_PORT), 'sim only: the simulated xela_server\'s port (another per hand)'),
    'netft_port': (str(NETFT_PORT), 'sim only: the simulated Net F/T box\'s UDP port'),
    'can_port': (str(CAN_PORT), 'sim only: the simulated hand\'s socketcand port'),
    'autostart': ('true', 'the lifecycle drivers (xela_driver, ft_bridge, allegro_driver) '
                  'configure and activate themselves; false: they start unconfigured, for '
                  'ros2 lifecycle set or a lifecycle manager'),
}


def _nodes(context, mode: str):
    value = {name: LaunchConfiguration(name).perform(context) for name in ARGUMENTS}
    args = SessionArgs(mode=mode, sim=launch_bool('sim', value['sim']),
                       hand_side=value['hand_side'], array=value['array'],
                       plate=value['plate'], scene=value['scene'],
                       model_config=value['model'], sequence=value['sequence'],
                       out=value['out'], campaign=value['campaign'],
                       real_time_factor=float(value['real_time_factor']),
                       lockstep=launch_bool('lockstep', value['lockstep']),
                       sim_duration=float(value['sim_duration']),
                       seed=int(value['seed']), compose=launch_bool('compose', value['compose']),
                       autostart=launch_bool('autostart', value['autostart']),
                       namespace=value['namespace'], frame_prefix=value['frame_prefix'],
                       xela_port=int(value['xela_port']), netft_port=int(value['netft_port']),
                       can_port=int(value['can_port']))
    if args.campaign:
        args = campaign_session(args)
    # All nodes start together (as in `session`): the hand driver waits for the first /clock,
    # which sim_world publishes once its emulators listen (on hardware: up to connect_timeout
    # for the hand), the XELA and F/T clients keep trying their devices, and the command player
    # starts its sequence only when the controller and the recorder listen.
    actions = []
    for node in plan(args):
        action = (Node(package='tacforce_ros', executable=node.executable, output='screen',
                       arguments=node.command_args()) if node.parts else
                  Node(package='tacforce_ros', executable=node.executable, output='screen',
                       namespace=node.namespace or None, remappings=list(node.remappings),
                       parameters=[str(p) for p in node.param_files] + [node.overrides]))
        actions.append(action)
        # A node that exits with an error ends the launch, naming itself (as `session` does).
        actions.append(RegisterEventHandler(OnProcessExit(
            target_action=action, on_exit=_shutdown_on_failure(node.executable))))
        if node.executable == 'sim_world':
            # The end of the scene (sim_duration): shut down, the drivers before the emulators.
            actions.append(RegisterEventHandler(OnProcessIO(
                target_action=action, on_stdout=_shutdown_when_done,
                on_stderr=_shutdown_when_done)))
    urdf = load_hand(hand_config(args.hand_side)).urdf_path    # plan() checked it exists
    actions.append(Node(package='robot_state_publisher', executable='robot_state_publisher',
                        namespace=args.namespace or None,
                        remappings=[('/clock', f'{args.namespace}/clock')]
                        if args.namespace and args.sim else [],
                        parameters=[{'robot_description': urdf.read_text(),
                                     'frame_prefix': args.frame_prefix,
                                     'use_sim_time': args.sim}]))
    return actions


def _shutdown_on_failure(name: str):
    def handler(event, context):
        if event.returncode not in (0, None):
            return [Shutdown(reason=f'{name} exited with code {event.returncode}')]
        return None
    return handler


def _shutdown_when_done(event):
    if SCENE_DONE_MARKER.encode() in event.text:
        return [Shutdown(reason='the scene ended (sim_duration)')]
    return None


def session_launch_description(mode: str) -> LaunchDescription:
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=text)
         for name, (default, text) in ARGUMENTS.items()]
        + [OpaqueFunction(function=_nodes, args=[mode])])
