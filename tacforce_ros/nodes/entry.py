"""The entry point of every node executable (setup.py): a stop asked for while the node's libraries
load ends the process at once, and a node that has stopped ends its process without Python's
finalization.

Why, measured with `bench_stop` and by timing each step of the way out (2-core machine running a
closed-loop session, load 4-6): loading rclpy, numpy and pinocchio took 1-4 s, and a SIGINT then
raised KeyboardInterrupt inside some import (a traceback, exit -2). After a node had left its
device safe, destroyed its node and shut rclpy down (a few ms), the interpreter's finalization
(the garbage collector over the whole heap, module teardown, the DDS library's destructors) took
0.2-6 s more. An allegro_driver in a fresh clone's suite that had logged its link counters at
close, the step before those, had not ended 10 s later: whether that finalization was slow or
stuck, nothing is left to do by then. The device is safe, bags are closed, the node has left the
ROS graph (ManagedDriver.destroy_node); so, once the log streams are flushed, the process ends
with os._exit, in 0.01-0.06 s under the same load.
"""
from __future__ import annotations

import ctypes
import functools
import importlib
import os
import signal
import sys
import traceback


def _stopped_while_loading(signum: int, _frame) -> None:
    """SIGINT or SIGTERM before the node exists: nothing is open yet, so the process just ends
    (run_nodes replaces this handler before it builds the node)."""
    name = os.path.basename(sys.argv[0]) if sys.argv else 'node'
    os.write(2, f'{name}: stopped by {signal.Signals(signum).name} while starting\n'.encode())
    os._exit(0)


def run(module: str) -> None:
    """Load tacforce_ros.nodes.<module>, run its main() and end the process with its exit code."""
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, _stopped_while_loading)
    main = importlib.import_module(f'tacforce_ros.nodes.{module}').main
    try:
        main()          # its run_nodes takes SIGINT and SIGTERM over first thing
        code = 0
    except SystemExit as end:
        if end.code is None or isinstance(end.code, int):
            code = end.code or 0
        else:                       # sys.exit('message'): printed, exit code 1
            print(end.code, file=sys.stderr)
            code = 1
    except BaseException:           # noqa: BLE001 - reported as Python would, then ended alike
        traceback.print_exc()
        code = 1
    _flush()
    os._exit(code)


def _flush() -> None:
    """Python's and C's buffered output (rcutils logs through C stdio) before os._exit."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):       # a closed pipe, a closed stream
            pass
    ctypes.CDLL(None).fflush(None)


# One entry per node executable, each running the node module of its name.
xela_driver = functools.partial(run, 'xela_driver')
ft_bridge = functools.partial(run, 'ft_bridge')
allegro_driver = functools.partial(run, 'allegro_driver')
force_controller = functools.partial(run, 'force_controller')
estimator = functools.partial(run, 'estimator')
sync_recorder = functools.partial(run, 'sync_recorder')
coverage_view = functools.partial(run, 'coverage_view')
command_player = functools.partial(run, 'command_player')
grasp_controller = functools.partial(run, 'grasp_controller')
grasp_client = functools.partial(run, 'grasp_client')
sim_world = functools.partial(run, 'sim_world')
tacforce_container = functools.partial(run, 'tacforce_container')
