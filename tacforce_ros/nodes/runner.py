"""main() of a node process: --help, rclpy init, build the node(s), spin until SIGINT/SIGTERM or
rclpy shutdown, leave things safe, exit with a code that says how it ended.

Distros. Uses only API present in Humble, Jazzy and Kilted; `SignalHandlerOptions` (Humble+) is
imported defensively.
"""
from __future__ import annotations

import argparse
import faulthandler
import os
import signal
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import rclpy
from rclpy.executors import Executor, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.utilities import remove_ros_args

from tacforce_ros.nodes.node_base import StopFlag, StopRequested, TacforceNode, half_built
from tacforce_ros.nodes.parameters import ParameterError, unmatched_params_files

EXIT_OK = 0
EXIT_FAILURE = 1          # an unexpected exception while running
EXIT_BAD_PARAMETERS = 2   # refused at start-up: the log names each bad parameter
EXIT_STOP_STUCK = 1       # faulthandler's own exit code (see STOP_LIMIT_S)

# The longest a stop (leaving devices safe, then ROS teardown) may take before every thread's
# stack goes to the log and the process ends with EXIT_STOP_STUCK: a hang is named, not left to
# SIGKILL (session's 10 s grace; ros2 launch's SIGKILL at 10 s).
STOP_LIMIT_S = 8.0


def _watch_stop() -> bool:
    """Arm the stop's watchdog (faulthandler's C thread: it fires even while the stop holds
    the GIL). False where stderr is no file (a node run inside a test's captured output)."""
    try:
        faulthandler.dump_traceback_later(STOP_LIMIT_S, exit=True, file=sys.stderr)
    except (AttributeError, OSError, ValueError):   # io.UnsupportedOperation is an OSError
        return False
    return True


def _init_without_rclpy_signal_handlers(args: Sequence[str] | None) -> None:
    try:    # Humble+: let run_node own SIGINT/SIGTERM so leave_safe always runs first
        from rclpy.signals import SignalHandlerOptions
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except (ImportError, TypeError):
        rclpy.init(args=args)


def parse_cli(node_cls: type[TacforceNode], args: Sequence[str]) -> None:
    """--help for a node: its docstring and parameter table; ROS arguments pass through."""
    lines = [f'  {s.name} (default {s.default!r}'
             + (f', range {list(s.range)}' if s.range else '')
             + (f', one of {list(s.choices)}' if s.choices else '')
             + (', writable' if not s.read_only else '') + f'): {s.description}'
             for s in node_cls.PARAMETERS]
    parser = argparse.ArgumentParser(
        prog=Path(args[0]).name if args else None, description=node_cls.__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog='parameters (set with --ros-args -p name:=value or --params-file FILE):\n'
        + '\n'.join(lines))
    parser.parse_args(remove_ros_args(list(args))[1:])


def events_executor() -> Executor:
    """rclpy's EventsExecutor (Jazzy and later), SingleThreadedExecutor where it is missing."""
    try:
        from rclpy.experimental import EventsExecutor
    except ImportError:         # Humble
        return SingleThreadedExecutor()
    return EventsExecutor()


def _destroy_half_built(nodes: list[TacforceNode]) -> None:
    half = half_built(nodes)
    if half is not None:
        try:
            half.destroy_node()
        except Exception:   # noqa: BLE001 - a constructor that failed may have left it partial
            pass


def run_node(node_cls: type[TacforceNode], args: Sequence[str] | None = None, *,
             threads: int = 1, executor: Callable[[], Executor] | None = None) -> int:
    """main() of a node: --help, rclpy init, build the node, `on_built()`, spin until
    SIGINT/SIGTERM or rclpy shutdown, then `leave_safe()`, destroy and shut down. Returns the
    exit code (EXIT_*; `sys.exit(run_node(MyNode))`).

    threads > 1 spins a MultiThreadedExecutor (needed when a callback waits on another one,
    e.g. a service handler that waits for a subscription); `executor`, if given, makes the
    executor instead (called once the node exists, e.g. rclpy's EventsExecutor); otherwise
    single-threaded.
    """
    args = list(sys.argv if args is None else args)
    parse_cli(node_cls, args)
    return run_nodes([(node_cls, None)], args, threads=threads, executor=executor)


def run_nodes(parts: Sequence[tuple[type[TacforceNode], Sequence[str] | None]],
              args: Sequence[str], *, threads: int = 1,
              executor: Callable[[], Executor] | None = None) -> int:
    """run_node for one or several nodes in this process, on one executor: each part is a node
    class and its own ROS arguments (None: the process's, `args`, which rclpy is initialised
    with). Built in order; any node's error ends them all; leave_safe() in reverse order.

    SIGINT and SIGTERM are handled from before rclpy.init on, and stay so (the process ends
    right after: nodes/entry.py). One that comes while the first node is being built ends the
    process there: nothing is open yet that leave_safe would close (nodes open devices and
    files in on_built), and a constructor has no waits that look at the stop. Later, it sets
    the stop every wait of a start-up, and the spin loop, look at."""
    stop = StopFlag()
    building = [False]

    def on_signal(signum: int, _frame) -> None:
        stop.set()
        if building[0] and not nodes:
            os.write(2, f'{parts[0][0].NODE_NAME}: stopped by {signal.Signals(signum).name} '
                     'while starting\n'.encode())
            os._exit(EXIT_OK)

    nodes: list[TacforceNode] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    _init_without_rclpy_signal_handlers(args)
    spinner = None
    logger = rclpy.logging.get_logger(parts[0][0].NODE_NAME)
    code = EXIT_OK
    try:
        try:
            for node_cls, node_args in parts:
                logger = rclpy.logging.get_logger(node_cls.NODE_NAME)
                try:
                    if stop.is_set():
                        raise StopRequested('stopped while starting')
                    building[0] = True
                    try:
                        node = (node_cls() if node_args is None else
                                node_cls(cli_args=list(node_args), use_global_arguments=False))
                    finally:
                        building[0] = False
                    nodes.append(node)
                    node.stop_event = stop
                    node.on_built()
                except ParameterError as exc:
                    logger.fatal(f'refusing to start: {exc}')
                    code = EXIT_BAD_PARAMETERS
                    _destroy_half_built(nodes)
                    return code
                except StopRequested as exc:
                    logger.info(f'{exc}: not started')
                    _destroy_half_built(nodes)
                    return code
                for message in unmatched_params_files(node, args if node_args is None
                                                      else node_args):
                    node.get_logger().warning(message)
            spinner = (executor() if executor is not None
                       else MultiThreadedExecutor(num_threads=threads) if threads > 1
                       else SingleThreadedExecutor())
            for node in nodes:
                spinner.add_node(node)
            # Short spin slices: a signal only sets `stop`, which is seen within 0.1 s.
            while not stop.is_set() and rclpy.ok():
                spinner.spin_once(timeout_sec=0.1)
        except Exception as exc:    # noqa: BLE001 - report, still leave things safe below
            logger.fatal(f'stopped by an error: {type(exc).__name__}: {exc}')
            code = EXIT_FAILURE
    finally:
        watched = _watch_stop()
        try:
            for node in reversed(nodes):
                try:
                    node.leave_safe()
                except Exception as exc:    # noqa: BLE001 - the others must still be left safe
                    node.get_logger().fatal(f'shutdown failed: {type(exc).__name__}: {exc}')
                    code = EXIT_FAILURE
            # A node that ended its job (finish()) or its stop with an exit code of its own.
            code = max([code, *(node.exit_code for node in nodes)])
        finally:
            if spinner is not None:
                spinner.shutdown()      # lets go of the nodes' handles first
            for node in nodes:
                node.destroy_node()
            rclpy.try_shutdown()
            if watched:
                faulthandler.cancel_dump_traceback_later()
    return code
