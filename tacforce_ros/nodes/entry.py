"""The entry point of every node executable (setup.py): a stop asked for while the node's libraries
load ends the process at once, and a node that has stopped ends its process without Python's
finalization.

Why, measured with `bench_stop` and by timing each step of the way out (2-core machine running a
closed-loop session, load 4-6): loading rclpy, numpy and pinocchio took 1-4 s, and a SIGINT then
raised KeyboardInterrupt inside some import (a traceback, exit -2). After a node had left its
device safe, destroyed its node and shut rclpy down (a few ms), the interpreter's finalization
(the garbage collector over the whole heap, module teardown, the DDS library's destructors) took
0.2-6 s more, and in a fresh clone's suite an allegro_driver that had logged its link counters at
close had not ended 10 s later. By then nothing is left to do: the device is safe, bags are
closed, the node has left the ROS graph (ManagedDriver.destroy_node), the logs are flushed; so the
process ends with os._exit, in 0.01-0.06 s under the same load.
"""
from __future__ import annotations

import importlib
import os
import signal
import sys
from collections.abc import Callable


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
        main()
        code = 0
    except SystemExit as end:
        if end.code is None or isinstance(end.code, int):
            code = end.code or 0
        else:                       # sys.exit('message'): printed, exit code 1
            from tacforce_ros.nodes.common import EXIT_FAILURE    # loaded by main() already
            print(end.code, file=sys.stderr)
            code = EXIT_FAILURE
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def _entry(module: str) -> Callable[[], None]:
    return lambda: run(module)


xela_driver = _entry('xela_driver')
ft_bridge = _entry('ft_bridge')
allegro_driver = _entry('allegro_driver')
force_controller = _entry('force_controller')
estimator = _entry('estimator')
sync_recorder = _entry('sync_recorder')
coverage_view = _entry('coverage_view')
command_player = _entry('command_player')
sim_world = _entry('sim_world')
tacforce_container = _entry('tacforce_container')
