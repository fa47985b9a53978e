"""The node graph of each session mode: the one source of truth that launch/*.launch.py and the
`session` tool both read, so both start the same executables with the same parameter files and
the same argument-derived overrides.

No rclpy here: the plan is data (executable, parameter files under config/params/, overrides).
"""
from __future__ import annotations

import dataclasses
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tacforce_ros.control.command_sequence import ForceSequence, SequenceError
from tacforce_ros.control.force_controller import (SAME_LINKS_AS_INDEX, ControllerConfigError,
                                                   ForceControllerConfig, finger_params_file)
from tacforce_ros.estimation.model_set import ModelConfigError, default_model_config, model_files
from tacforce_ros.hand.description import (DEFAULT_SIDE, FRAME_PREFIX_PATTERN, SIDES, hand_config,
                                           load_hand)
from tacforce_ros.paths import config_dir, ros_home
from tacforce_ros.sim.scene import (SceneError, calibration_scene_name, closed_loop_scene_name,
                                    load_scene)

MODES = ('calibration', 'closed_loop', 'grasp')
NAMESPACE = re.compile(r'(/[A-Za-z_][A-Za-z0-9_]*)+')

# Default device ports of the hardware; in simulation sim_world serves the emulators on these
# (or on the ports a test chose) on 127.0.0.1.
XELA_PORT = 5000        # xela_server's default WebSocket port
NETFT_PORT = 49152      # ATI RDT UDP port
CAN_PORT = 29536        # socketcand's default TCP port


# The simulated hand streams from a thread of sim_world, which shares the CPU with the whole
# graph: on a 2-core shared machine its joint stream stalled for 1-2.4 s (`session calibration`
# logs, 2026-11-23), beyond the hardware default of 2 s. A stall is a slower run, not a silent
# hand: simulated sessions make the hand safe only after a silence no stall reaches.
SIM_SILENT_TIMEOUT_S = 10.0

# sim_world's log line when its scene has run `stop_after` simulated seconds: time then stands
# still with the devices still served, and whoever runs the session (the `session` tool, launch's
# OnProcessIO handler) stops the nodes, the drivers before their devices go.
SCENE_DONE_MARKER = 'scene done:'
SESSION_SCENE_ENDED = 'session: the scene ended'     # the `session` tool's word for it


class PlanError(ValueError):
    """Session arguments that cannot make a node graph; the message says which and why."""


@dataclass(frozen=True)
class NodeLaunch:
    """One node: its installed executable, parameter files (in order) and overrides; or, with
    `parts`, a tacforce_container process hosting those nodes."""

    executable: str
    param_files: tuple[Path, ...] = ()
    overrides: dict[str, Any] = field(default_factory=dict)
    parts: tuple[NodeLaunch, ...] = ()
    namespace: str = ''               # '' : the root namespace
    remappings: tuple[tuple[str, str], ...] = ()
    finishes: bool = False            # a client: its clean exit ends the session (its result)

    def ros_args(self) -> list[str]:
        """Command-line arguments giving the node exactly these parameters, namespace and
        remappings."""
        args = ['--ros-args']
        if self.namespace:
            args += ['-r', f'__ns:={self.namespace}']
        for source, target in self.remappings:
            args += ['-r', f'{source}:={target}']
        for path in self.param_files:
            args += ['--params-file', str(path)]
        for name, value in self.overrides.items():
            args += ['-p', f'{name}:={_ros_literal(value)}']
        return args

    def command_args(self) -> list[str]:
        """The process's arguments: the node's ROS arguments, or the container's node groups."""
        if not self.parts:
            return self.ros_args()
        return [arg for part in self.parts for arg in ('--node', part.executable,
                                                       *part.ros_args())]


CONTAINER = 'tacforce_container'


def composed(nodes: list[NodeLaunch]) -> list[NodeLaunch]:
    """The same nodes with every one but the simulator and a client in one tacforce_container
    process (the simulator stands for the hardware, which is not composed with its drivers; a
    client's end is the session's, not the container's)."""
    devices = [n for n in nodes if n.executable == 'sim_world' or n.finishes]
    return devices + [NodeLaunch(CONTAINER, parts=tuple(n for n in nodes if n not in devices))]


@dataclass(frozen=True)
class SessionArgs:
    """What a user chooses for a session (the launch files' arguments)."""

    mode: str
    sim: bool = True
    hand_side: str = DEFAULT_SIDE
    array: str = 'index_tip'
    plate: str = 'spherical'           # push-plate (calibration) or object (closed loop)
    grasp_object: str = 'golf_ball'    # grasp: the object held (sim: scene grasp_<object>)
    grip: float = 1.0                  # grasp: grip force (N)
    hold_time: float = 0.0             # grasp: s to hold, then release; 0: until the end
    scene: str = ''                    # empty: derived from mode, array and plate
    model_config: str = ''             # estimator models YAML; empty: the params file's
    sequence: str = ''                 # closed loop: force command sequence (a name in
    #                                    config/commands/ or a path); empty: the params file's
    out: str = 'bags'                  # bag folder of the recorder
    real_time_factor: float = 1.0     # sim: an upper bound under lockstep
    lockstep: bool = True              # sim: simulated time waits for the loop's consumers
    sim_duration: float = 0.0          # sim: simulated seconds the scene runs; 0 = until stopped
    compose: bool = False              # the nodes (not the simulator) in one process
    autostart: bool = True             # the managed drivers configure and activate themselves
    namespace: str = ''                # every node in this namespace (e.g. /left); '': the root
    frame_prefix: str = ''             # before every frame id the nodes publish (e.g. left/)
    campaign: str = ''                 # calibration: record the next due session of this
    #                                    campaign folder (its array, plate, length, seed)
    seed: int = -1                     # simulator seed; -1: the scene's own
    xela_port: int = XELA_PORT
    netft_port: int = NETFT_PORT
    can_port: int = CAN_PORT
    # Names what belongs to this session alone (the estimator's saved tare, which a restarted
    # estimator loads): the start time and the process that planned it.
    session_id: str = field(
        default_factory=lambda: f'{time.strftime("%Y%m%d_%H%M%S")}_{os.getpid()}')

    def scene_name(self) -> str:
        if self.scene:
            return self.scene
        if self.mode == 'calibration':
            return calibration_scene_name(self.array, self.plate)
        if self.mode == 'grasp':
            return f'grasp_{self.grasp_object}'
        return closed_loop_scene_name(self.array, self.plate)


def launch_bool(name: str, text: str) -> bool:
    """A boolean launch argument as launch's own conditions read one (true/false/1/0, any
    case); anything else is refused, so that `sim:=yes` cannot quietly start the hardware graph."""
    value = text.strip().lower()
    if value not in ('true', 'false', '1', '0'):
        raise PlanError(f'{name}:={text!r}: expected true or false (or 1 or 0)')
    return value in ('true', '1')


def launch_number(name: str, text: str, kind: type = float) -> float | int:
    """A numeric launch argument (float or int), or PlanError naming it."""
    try:
        return kind(text.strip())
    except ValueError:
        raise PlanError(f'{name}:={text!r}: expected {"an integer" if kind is int else "a number"}'
                        ) from None


# What only one mode, or only simulation, reads: refused where it would be ignored.
ONLY_FOR_MODE = {'model_config': ('closed_loop', 'grasp'), 'sequence': ('closed_loop',),
                 'campaign': ('calibration',), 'grasp_object': ('grasp',), 'grip': ('grasp',),
                 'hold_time': ('grasp',)}
SIM_ONLY = ('scene', 'real_time_factor', 'lockstep', 'sim_duration', 'seed', 'xela_port',
            'netft_port', 'can_port', 'grip', 'hold_time')
# The launch files' names of SessionArgs fields that differ from them.
ARGUMENT_NAMES = {'model_config': 'model', 'grasp_object': 'object'}
PLATE_NAME = re.compile(r'[a-z][a-z0-9_]*')


def check_arguments(args: SessionArgs, hand: Any) -> None:
    """PlanError for an argument the session would ignore or could not use: one meant for the
    other mode or for simulation alone, an array the hand does not have, a plate name that cannot
    name a bag, a port out of range."""
    defaults = {f.name: f.default for f in dataclasses.fields(SessionArgs)}
    for name, modes in ONLY_FOR_MODE.items():
        if getattr(args, name) != defaults[name] and args.mode not in modes:
            raise PlanError(f'{ARGUMENT_NAMES.get(name, name)}: only a {" or ".join(modes)} '
                            f'session reads it; this is a {args.mode} session')
    if not args.sim:
        given = [name for name in SIM_ONLY if getattr(args, name) != defaults[name]]
        if given:
            them = 'them' if len(given) > 1 else 'it'
            raise PlanError(f'{", ".join(given)}: only simulation reads {them} (sim is false: '
                            'the devices are the hardware)')
    arrays = [a.name for a in hand.arrays]
    if args.array not in arrays:
        raise PlanError(f'array: {args.array!r} is not an array of the {hand.side} hand '
                        f'(its arrays: {", ".join(arrays)})')
    if not PLATE_NAME.fullmatch(args.plate):
        raise PlanError(f'plate: {args.plate!r} is not a plate name (lower-case letters, digits '
                        'and _, as the bags are named after it)')
    if not PLATE_NAME.fullmatch(args.grasp_object):
        raise PlanError(f'object: {args.grasp_object!r} is not an object name (lower-case '
                        'letters, digits and _)')
    from tacforce_ros.control.grasp import GraspConfig
    if not (args.grip >= GraspConfig.grip_min and args.hold_time >= 0):
        raise PlanError(f'grip {args.grip} N, hold_time {args.hold_time} s: the grip must be at '
                        f'least {GraspConfig.grip_min:g} N (below, the estimate cannot tell it '
                        'from noise) and the hold time at least 0')
    if not args.real_time_factor > 0:
        raise PlanError(f'real_time_factor: {args.real_time_factor} must be above 0')
    ports = {'xela_port': args.xela_port, 'netft_port': args.netft_port,
             'can_port': args.can_port}
    for name, port in ports.items():
        if not 1 <= port <= 65535:
            raise PlanError(f'{name}: {port} is not a port (1-65535)')
    if len(set(ports.values())) < len(ports):
        raise PlanError(f'xela_port, netft_port, can_port: {sorted(ports.values())} must differ')


def tare_file(session_id: str, namespace: str = '') -> Path:
    """Where a session's estimator keeps its tare: under ROS_HOME (~/.ros), not among the bags;
    one per namespace (two hands planned in the same second by one process)."""
    hand = namespace.strip('/').replace('/', '_')
    suffix = f'_{hand}' if hand else ''
    return ros_home() / 'tacforce_ros' / f'estimator_tare_{session_id}{suffix}.npz'


def params_file(name: str) -> Path:
    return config_dir() / 'params' / f'{name}.yaml'


def params_node_key(name: str) -> str:
    """The node key of a shipped parameters file: the node in any namespace (rcl's `**`)."""
    return f'/**/{name}'


def shipped_parameters(name: str) -> dict[str, Any]:
    """The ros__parameters a shipped parameters file gives node `name`."""
    import yaml
    return yaml.safe_load(params_file(name).read_text())[params_node_key(name)]['ros__parameters']


def _ros_literal(value: Any) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        # Quoted: ROS reads -p values as YAML, where off, N, yes ... would become booleans.
        return "'" + value.replace("'", "''") + "'"
    return repr(value)


@dataclass(frozen=True)
class FingertipLoop:
    """What the closed loop on one fingertip sets in the graph."""
    controller_files: tuple[Path, ...]      # force_controller's parameter files, in order
    controller: dict[str, Any]              # its overrides
    rig_frame: str                          # the F/T frame of the rig mounted for the finger


def fingertip_loop(args: SessionArgs, hand: Any) -> FingertipLoop:
    """The closed loop on `args.array`, which must be a fingertip the estimator has a model
    for (ForceControllerConfig.pressing_with says what the controller needs)."""
    if args.array not in {a.name for a in hand.arrays}:
        raise PlanError(f'array: {args.array!r} is not an array of the {hand.side} hand')
    tip = hand.array(args.array)
    config = ForceControllerConfig.from_yaml(params_file('force_controller'))
    try:
        config = config.pressing_with(tip, hand.rig_frame(tip.finger))
    except ControllerConfigError as exc:
        raise PlanError(f'array: {exc}') from None
    models_yaml = args.model_config or default_model_config(hand)
    try:
        models = model_files(models_yaml)
    except ModelConfigError as exc:
        raise PlanError(f'model: {exc}') from None
    if args.array not in models:
        raise PlanError(f'array: {models_yaml} has no model for {args.array}, whose estimate '
                        f'closes the loop (it has {sorted(models)})')
    # pressing_with took this finger's own gains from its file: the node loads it too.
    own = () if config.finger in SAME_LINKS_AS_INDEX else (finger_params_file(config.finger),)
    files = (params_file('force_controller'),) + own
    return FingertipLoop(files, {'estimate_array': args.array,
                                 'force_controller.finger': config.finger,
                                 'force_controller.estimate_frame': config.estimate_frame,
                                 'force_controller.force_frame': config.force_frame},
                         config.force_frame)


def campaign_session(args: SessionArgs) -> SessionArgs:
    """`args` set to record the next session `args.campaign` has due: its array and plate, into
    the campaign folder; in simulation its length and seed unless given (a session recorded
    again after a poor one gets the next seed). Bags not yet judged are judged as `campaign
    status` judges them: a poor one is set aside in rejected/, the verdicts are kept."""
    from tacforce_ros.hand.kinematics import HandKinematics
    from tacforce_ros.recording.campaign import Campaign, CampaignError
    from tacforce_ros.sim.scene import session_seed
    if args.mode != 'calibration':
        raise PlanError('campaign: a campaign records calibration sessions')
    try:
        campaign = Campaign(args.campaign)
    except (CampaignError, OSError) as exc:
        raise PlanError(f'campaign: {exc}') from None
    plan_ = campaign.plan
    if plan_.hand_side != args.hand_side:
        raise PlanError(f'campaign: {args.campaign} is a campaign of the {plan_.hand_side} hand; '
                        f'hand_side is {args.hand_side}')
    hand = load_hand(hand_config(args.hand_side))
    due = campaign.due(campaign.check(hand, HandKinematics(hand.urdf_path)))
    if not due:
        raise PlanError(f'campaign: {args.campaign} is complete, nothing is due (train it: '
                        f'`train {args.campaign} --out MODELS`)')
    slot = due[0]
    simulated = {'sim_duration': args.sim_duration or plan_.session_seconds(slot.array),
                 'seed': session_seed(plan_.seed, slot.array, slot.plate, slot.index
                                      + campaign.rejected_count(slot.array, slot.plate))
                 if args.seed == -1 else args.seed} if args.sim else {}
    return dataclasses.replace(args, array=slot.array, plate=slot.plate, scene='',
                               out=str(campaign.folder), **simulated)


# two_hands_sim: each simulated hand in the namespace of its side, with device ports of its own
# (the right hand on the hardware defaults).
TWO_HANDS_PORTS = {'right': (XELA_PORT, NETFT_PORT, CAN_PORT), 'left': (5010, 49162, 29546)}
# What two_hands() sets per hand, so a two-hand launch takes none of them.
PER_HAND = ('hand_side', 'namespace', 'frame_prefix', 'xela_port', 'netft_port', 'can_port',
            'model_config', 'scene', 'campaign')


def two_hands(args: SessionArgs) -> list[SessionArgs]:
    """The closed-loop sessions of two simulated hands in one ROS graph (two_hands_sim.launch.py):
    `args` (what both share) for each side, in namespace /<side> with that side's description,
    models, frame prefix <side>/ and device ports, its bags in <out>/<side>. PlanError when `args`
    sets what is per hand, or is not a simulated closed loop."""
    defaults = {f.name: f.default for f in dataclasses.fields(SessionArgs)}
    given = [ARGUMENT_NAMES.get(n, n) for n in PER_HAND if getattr(args, n) != defaults[n]]
    if given:
        raise PlanError(f'{", ".join(given)}: set per hand by the two-hand session, not an '
                        'argument of it')
    if args.mode != 'closed_loop' or not args.sim:
        raise PlanError('two hands: a simulated closed-loop session only')
    return [dataclasses.replace(args, hand_side=side, namespace=f'/{side}',
                                frame_prefix=f'{side}/', out=str(Path(args.out) / side),
                                xela_port=xela, netft_port=netft, can_port=can)
            for side, (xela, netft, can) in TWO_HANDS_PORTS.items()]


def grasp_model_config(args: SessionArgs, hand: Any) -> tuple[str, dict]:
    """The estimator's models of a grasp session, which must model the thumb's fingertip (every
    grasp opposes the thumb) and another: (its YAML, its model files by array)."""
    models_yaml = args.model_config or str(default_model_config(hand))
    try:
        models = model_files(models_yaml)
    except ModelConfigError as exc:
        raise PlanError(f'model: {exc}') from None
    tips = [f'{f}_tip' for f in ('thumb', 'index', 'middle', 'ring') if f'{f}_tip' in models]
    if 'thumb_tip' not in tips or len(tips) < 2:
        raise PlanError(f'model: {models_yaml} models {tips or "no fingertip"}; a grasp needs '
                        'the thumb\'s fingertip and another')
    return models_yaml, models


def grasp_nodes(args: SessionArgs, scene: Any, models_yaml: str, common: dict, hand_param: dict,
                framed: dict, managed: dict, allegro: dict) -> list[NodeLaunch]:
    """A grasp session's estimator, hand driver and grasp_controller; in simulation also the
    grasp_client that sends the scene's goal at its `goal_at` (on the hardware, goals come from
    the user: `grasp_client` with their targets, or their own action client). In simulation the
    hand is mounted as the scene has it (its gravity for the driver's holds and the law's)."""
    mount = ({'gravity': [float(v) for v in scene.grasp['gravity']]}
             if scene is not None else {})
    nodes = [
        NodeLaunch('estimator', (params_file('estimator'),), {
            **common, **hand_param, **framed,
            'tare_file': str(tare_file(args.session_id, args.namespace)),
            **({'model_config': args.model_config} if args.model_config else {})}),
        NodeLaunch('allegro_driver', (params_file('allegro_driver'),),
                   {**common, **managed, **hand_param, **allegro, **mount, 'control': 'torque'}),
        NodeLaunch('grasp_controller', (params_file('grasp_controller'),),
                   {**common, **hand_param, **framed, **mount, 'model_config': models_yaml})]
    if scene is not None:
        nodes.append(NodeLaunch('grasp_client', (params_file('grasp_client'),), {
            **common, **hand_param, **mount, 'scene': args.scene_name(),
            'fingers': list(scene.grasp['fingers']), 'grip_force': float(args.grip),
            'object_mass': -1.0, 'hold_time': float(args.hold_time),
            'start_time': float(scene.grasp['goal_at'])}, finishes=True))
    return nodes


def plan(args: SessionArgs) -> list[NodeLaunch]:
    """The nodes of one session, in start order (the clock source first); `args` with a
    campaign are campaign_session's."""
    if args.mode not in MODES:
        raise PlanError(f'mode: {args.mode!r} is not one of {list(MODES)}')
    if args.sim_duration < 0:
        raise PlanError(f'sim_duration: {args.sim_duration} must be >= 0 (0: until stopped)')
    if args.seed < -1:
        raise PlanError(f'seed: {args.seed} must be >= 0, or -1 for the scene\'s own')
    if args.namespace and not NAMESPACE.fullmatch(args.namespace):
        raise PlanError(f'namespace: {args.namespace!r} is not a ROS namespace (/name or '
                        '/name/name, letters, digits and _, not starting with a digit)')
    if not re.fullmatch(FRAME_PREFIX_PATTERN[0], args.frame_prefix):
        raise PlanError(f'frame_prefix: {args.frame_prefix!r} is not {FRAME_PREFIX_PATTERN[1]}')
    if args.hand_side not in SIDES:
        raise PlanError(f'hand_side: {args.hand_side!r} is not one of {list(SIDES)}')
    hand = hand_config(args.hand_side)
    if not hand.is_file():
        raise PlanError(f'hand_side {args.hand_side!r}: no hand description {hand}')
    description = load_hand(hand)
    check_arguments(args, description)
    loop = fingertip_loop(args, description) if args.mode == 'closed_loop' else None
    grasp_models = grasp_model_config(args, description) if args.mode == 'grasp' else None
    scene = None
    if args.sim:
        try:
            scene = load_scene(args.scene_name())     # before any node starts, not in sim_world
        except (SceneError, OSError) as exc:
            raise PlanError(f'scene: {exc}') from exc
        if scene.kind != args.mode:
            raise PlanError(f'scene {scene.name!r} is a {scene.kind} scene, not {args.mode}')
        if args.mode == 'grasp':
            unmodelled = [f for f in scene.grasp['fingers'] if f'{f}_tip' not in grasp_models[1]]
            if unmodelled:
                raise PlanError(f'model: {grasp_models[0]} has no model of {unmodelled}\'s '
                                f'fingertip, which scene {scene.name!r} grasps with')
            from tacforce_ros.control.force_controller import ForceControllerConfig
            from tacforce_ros.control.grasp import scene_grip_top
            top = scene_grip_top(scene, description, ForceControllerConfig())
            if args.grip > top:
                raise PlanError(
                    f'grip {args.grip:g} N: at most {top:.2f} N at scene {scene.name!r}\'s '
                    'start pose, where a joint of the grasp would need more than its torque '
                    'limit above it (the grasp controller refuses such a goal)')
        if args.mode != 'grasp' and scene.array not in {a.name for a in description.arrays}:
            raise PlanError(f'scene {scene.name!r} presses {scene.array!r}, not an array of the '
                            f'{description.side} hand')
    if args.sequence:
        try:
            ForceSequence.load(args.sequence)    # a bad sequence fails before any node starts
        except (SequenceError, OSError) as exc:
            raise PlanError(f'sequence: {exc}') from exc
    common: dict[str, Any] = {'use_sim_time': True} if args.sim else {}
    hand_param = {'hand_config': str(hand)}
    # The nodes that publish or check frame ids (a prefix-less graph passes nothing).
    framed = {'frame_prefix': args.frame_prefix} if args.frame_prefix else {}
    managed = {'autostart': args.autostart}     # the lifecycle drivers
    nodes: list[NodeLaunch] = []
    if args.sim:
        nodes.append(NodeLaunch('sim_world', (params_file('sim_world'),), {
            'scene': args.scene_name(), 'seed': args.seed,
            'real_time_factor': float(args.real_time_factor), 'lockstep': args.lockstep,
            'stop_after': float(args.sim_duration),
            'xela_port': args.xela_port, 'netft_port': args.netft_port,
            'can_port': args.can_port, **hand_param, **framed}))
    sim_devices = ({'xela': {'url': f'ws://127.0.0.1:{args.xela_port}'},
                    'netft': {'host': '127.0.0.1', 'port': args.netft_port},
                    'allegro': {'interface': 'socketcand', 'channel': 'can0',
                                'host': '127.0.0.1', 'port': args.can_port,
                                'rtr_requests': False,
                                'silent_timeout': SIM_SILENT_TIMEOUT_S}}
                   if args.sim else {'xela': {}, 'netft': {}, 'allegro': {}})
    nodes.append(NodeLaunch('xela_driver', (params_file('xela_driver'),),
                            {**common, **managed, **hand_param, **framed,
                             **sim_devices['xela']}))
    # A finger whose pad faces another way pushes on the rig mounted for it: {F} is that frame.
    rig = ({'frame_id': loop.rig_frame}
           if loop is not None and loop.rig_frame != description.ft_frame else {})
    if args.mode != 'grasp':     # a grasp has no F/T sensor: the truth is the skin's own
        nodes.append(NodeLaunch('ft_bridge', (params_file('ft_bridge'),),
                                {**common, **managed, **framed, **sim_devices['netft'],
                                 **rig}))
    if args.mode == 'grasp':
        nodes += grasp_nodes(args, scene, grasp_models[0], common, hand_param, framed, managed,
                             sim_devices['allegro'])
    elif args.mode == 'calibration':
        # The operator moves the hand: joint states only, no torque commands.
        nodes.append(NodeLaunch('allegro_driver', (params_file('allegro_driver'),),
                                {**common, **managed, **hand_param,
                                 **sim_devices['allegro'], 'control': 'off'}))
        # What the operator watches while pressing.
        nodes.append(NodeLaunch('coverage_view', (params_file('coverage_view'),), {
            **common, **hand_param, 'plate': args.plate, 'campaign': args.campaign,
            **({'session_seconds': float(args.sim_duration)} if args.sim else {})}))
    else:
        nodes.append(NodeLaunch('estimator', (params_file('estimator'),), {
            **common, **hand_param, **framed,
            'tare_file': str(tare_file(args.session_id, args.namespace)),
            **({'model_config': args.model_config} if args.model_config else {})}))
        # The hand, then the controller that sends it the finger's torques.
        nodes.append(NodeLaunch('allegro_driver', (params_file('allegro_driver'),),
                                {**common, **managed, **hand_param,
                                 **sim_devices['allegro'], 'control': 'torque'}))
        nodes.append(NodeLaunch('force_controller', loop.controller_files,
                                {**common, **hand_param, **framed, **loop.controller}))
        # The sequence starts once the controller and the recorder both listen.
        nodes.append(NodeLaunch('command_player', (params_file('command_player'),),
                                {**common, **framed, 'min_subscribers': 2, **rig,
                                 **({'sequence': args.sequence} if args.sequence else {})}))
    # Both modes keep the raw streams (closed loop: the F/T reading is the reference). Listed
    # right after the simulator, as one starts `ros2 bag record` first; what makes a closed-loop
    # bag whole is that the recorder listens to the command topic only once it records every
    # input, and the player waits for it (a recorder started last once missed the first 0.56 s
    # of simulated F/T readings on a loaded host: DDS discovery).
    recorder = NodeLaunch('sync_recorder', (params_file('sync_recorder'),), {
        **common, **hand_param, 'output_dir': args.out, 'array': args.array,
        'plate': (args.plate if args.mode != 'grasp' else
                  scene.grasp_object.name if scene is not None else args.grasp_object),
        'source': 'sim' if args.sim else 'lab', 'autostart': True,
        **({'scene': args.scene_name(), 'seed': args.seed} if args.sim else {})})
    nodes.insert(1 if args.sim else 0, recorder)
    if args.namespace:
        # Each simulated hand keeps its own simulated time: /clock inside its namespace.
        clock = ((('/clock', f'{args.namespace}/clock'),) if args.sim else ())
        nodes = [dataclasses.replace(n, namespace=args.namespace, remappings=clock)
                 for n in nodes]
    return composed(nodes) if args.compose else nodes
