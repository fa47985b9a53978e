"""tacforce_container: several of the package's nodes in one process, on one executor (the
Python counterpart of rclcpp_components' component container: rclpy has no loadable components).

    tacforce_container --node estimator --ros-args --params-file estimator.yaml -p a:=1 \
                       --node allegro_driver --ros-args --params-file allegro_driver.yaml ...

Each `--node NAME` starts a group: the node NAME (an executable of this package) and its own ROS
arguments, which reach only that node (as `ros2 run tacforce_ros NAME --ros-args ...` would
give them). The nodes are built in the order given, each waiting for what it waits for at
start-up (the hand driver for /clock), and spun together on one SingleThreadedExecutor; a node's
error ends the process (exit code 1), as a crash of a component ends its container. (rclpy's
EventsExecutor, which the estimator spins on its own, starved the controller's sim-time timer
here: a 25 s composed closed-loop session ran at 0.53x with the controller silent for 1 s 21
times, against 0.81x and none on the SingleThreadedExecutor; `session closed_loop --compose
--sim-duration 25`, this machine, one run each.) Ctrl-C shuts them down in reverse order. The nodes'
own threads (device links, the simulator) run as they do in their own processes; one process
means one Python interpreter lock for all of them (session --compose and bench_graph --compose
measure what that costs).
"""
from __future__ import annotations

import sys
from collections.abc import Sequence

import importlib

from tacforce_ros.nodes.node_base import TacforceNode
from tacforce_ros.nodes.runner import EXIT_BAD_PARAMETERS, run_nodes

# Node name (= its executable and module under tacforce_ros.nodes): its class, imported only
# when hosted (the simulator's module alone pulls in MuJoCo).
NODE_CLASSES = {'xela_driver': 'XelaDriver', 'ft_bridge': 'FtBridge',
                'allegro_driver': 'AllegroDriver', 'force_controller': 'ForceControllerNode',
                'estimator': 'Estimator',
                'sync_recorder': 'SyncRecorder', 'coverage_view': 'CoverageViewNode',
                'command_player': 'CommandPlayer',
                'grasp_controller': 'GraspControllerNode',
                'sim_world': 'SimWorld'}
USAGE = ('usage: tacforce_container --node NAME [--ros-args ...] [--node NAME ...]; NAME one of '
         + ', '.join(NODE_CLASSES))


def node_class(name: str) -> type[TacforceNode]:
    return getattr(importlib.import_module(f'tacforce_ros.nodes.{name}'), NODE_CLASSES[name])


def node_groups(args: Sequence[str]) -> list[tuple[type[TacforceNode], list[str]]]:
    """The (node class, its ROS arguments) of each `--node NAME ...` group; ValueError saying
    what is wrong."""
    groups: list[tuple[type[TacforceNode], list[str]]] = []
    rest = list(args)
    if not rest or rest[0] != '--node':
        raise ValueError(USAGE)
    while rest:
        if rest[0] != '--node' or len(rest) < 2:
            raise ValueError(USAGE)
        name, rest = rest[1], rest[2:]
        if name not in NODE_CLASSES:
            raise ValueError(f'--node {name!r}: not a node of this package ({USAGE})')
        end = rest.index('--node') if '--node' in rest else len(rest)
        groups.append((node_class(name), rest[:end]))
        rest = rest[end:]
    names = [cls.NODE_NAME for cls, _ in groups]
    if len(set(names)) != len(names):
        raise ValueError(f'a node named twice: {names}')
    return groups


def main(args: list[str] | None = None) -> None:
    args = list(sys.argv if args is None else args)
    if any(a in ('-h', '--help') for a in args[1:2]):
        print(__doc__ + '\n' + USAGE)
        sys.exit(0)
    try:
        groups = node_groups(args[1:])
    except ValueError as exc:
        print(f'tacforce_container: {exc}', file=sys.stderr)
        sys.exit(EXIT_BAD_PARAMETERS)
    sys.exit(run_nodes(groups, args[:1]))


if __name__ == '__main__':
    main()
