"""A session's node processes: started together as launch starts them, stopped as launch stops
them (SIGINT, a grace period, then SIGKILL), with their CPU time; and a command that starts
processes of its own (`session`) run to its end by a tool that is itself stopped meanwhile.
Shared by the `session` tool, the benchmarks, the main job and the tests that run node graphs."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from tacforce_ros.bringup.session_plan import NodeLaunch

EXECUTABLES = Path(sys.prefix) / 'lib' / 'tacforce_ros'


def executable(name: str) -> Path:
    """The installed executable (ament layout lib/<package>/<name>) of a node or tool."""
    path = EXECUTABLES / name
    if not path.is_file():
        raise FileNotFoundError(f'{path} is not installed; run ./run.sh setup')
    return path


def start_nodes(nodes: list[NodeLaunch], log_dir: Path, env: dict[str, str] | None = None,
                log_mode: str = 'w') -> list[tuple[str, subprocess.Popen]]:
    """Start the nodes together, in plan order, as launch does: none waits for another (the
    drivers wait for their devices themselves, sim time for the first /clock). `log_mode` 'a':
    a restarted node goes on in its log."""
    log_dir.mkdir(parents=True, exist_ok=True)
    procs = []
    for node in nodes:
        with open(log_dir / f'{node.executable}.log', log_mode) as log:   # the child keeps one
            proc = subprocess.Popen([str(executable(node.executable)), *node.command_args()],
                                    stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                                    env=env)
        procs.append((node.executable, proc))
    return procs


def first_exited(procs: list[tuple[str, subprocess.Popen]]) -> tuple[str, int] | None:
    """(name, exit code) of the first node in `procs` that is no longer running, or None."""
    return next(((name, proc.returncode) for name, proc in procs if proc.poll() is not None),
                None)


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU seconds a running process has used, all its threads (Linux /proc;
    None elsewhere or once it is gone)."""
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except OSError:
        return None
    # after the command name: state is field 3 of proc(5), utime and stime fields 14 and 15
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


CPU_REPORT = 'session: CPU seconds per process:'
EXIT_CODES_REPORT = 'exit codes'    # then name=code, ... (negative: killed by that signal)


def cpu_report(cpu: dict[str, float | None]) -> str:
    """The line a session prints at its end: CPU seconds per process (gone ones left out)."""
    return f'{CPU_REPORT} ' + ', '.join(f'{name}={seconds:.1f}' for name, seconds in cpu.items()
                                        if seconds is not None)


def read_cpu_report(line: str) -> dict[str, float] | None:
    """The figures of a cpu_report() line; None for any other line."""
    if not line.startswith(CPU_REPORT):
        return None
    return {name: float(value) for name, value in
            (item.split('=') for item in line[len(CPU_REPORT):].strip().split(', ') if item)}


def exit_codes_report(codes: dict[str, int]) -> str:
    """How a session's processes ended, as its last status line says it (stop_nodes' codes)."""
    return f'{EXIT_CODES_REPORT} ' + ', '.join(f'{name}={code}' for name, code in codes.items())


def read_exit_codes(line: str) -> dict[str, int] | None:
    """The codes of a line holding exit_codes_report(); None for any other line."""
    at = line.find(EXIT_CODES_REPORT + ' ')
    if at < 0:
        return None
    return {name: int(code) for name, code in
            (item.split('=') for item in line[at + len(EXIT_CODES_REPORT):].strip().split(', ')
             if item)}


def unclean_exits(codes: dict[str, int]) -> dict[str, int]:
    """The processes that did not end as asked: any code but 0, or the SIGINT a node gets when
    it is stopped while Python itself is still starting (before any of its code ran)."""
    return {name: code for name, code in codes.items() if code not in (0, -signal.SIGINT)}


SLOW_STOP_S = 1.0      # a node's stop longer than this is named


def stop_nodes(procs: list[tuple[str, subprocess.Popen]], grace: float) -> dict[str, int]:
    """SIGINT to every node (reverse start order: the recorder and controllers first, the clock
    source last), wait up to `grace` s in total, then kill what is left. Returns exit codes
    (negative: killed by that signal)."""
    for _, proc in reversed(procs):
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    signalled = time.monotonic()
    deadline = signalled + grace
    took: dict[int, float] = {}         # when each ended, to name what holds a slow stop up
    while len(took) < len(procs) and time.monotonic() < deadline:
        for i, (_, proc) in enumerate(procs):
            if i not in took and proc.poll() is not None:
                took[i] = time.monotonic() - signalled
        time.sleep(0.01)
    for name, proc in procs:
        if proc.poll() is None:
            print(f'session: {name} did not stop within {grace:g} s; killing it',
                  file=sys.stderr)
            proc.kill()
            proc.wait(timeout=5.0)
    slow = [f'{procs[i][0]} {t:.2f} s' for i, t in sorted(took.items()) if t > SLOW_STOP_S]
    if slow:
        print('session: slow to stop: ' + ', '.join(slow), file=sys.stderr)
    return {name: proc.returncode for name, proc in procs}


def interrupt_on_sigterm() -> None:
    """SIGTERM raises KeyboardInterrupt, as SIGINT does: a tool's `finally` blocks then stop what
    it started (otherwise SIGTERM ends it at once and leaves its children running)."""
    signal.signal(signal.SIGTERM, signal.default_int_handler)


def run_to_end(command: list[str], timeout: float, grace: float = 10.0,
               **popen) -> subprocess.CompletedProcess:
    """subprocess.run(capture_output=True, text=True) for a command that starts processes of
    its own: run in a process session of its own, and stopped as a user stops it (SIGINT, up to
    `grace` s, then SIGKILL) when `timeout` passes (subprocess.TimeoutExpired, as run raises) or
    the caller is interrupted; subprocess.run would SIGKILL it and leave its children running."""
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, **popen)
    try:
        out, err = proc.communicate(timeout=timeout)
    except BaseException:
        proc.send_signal(signal.SIGINT)
        try:
            proc.communicate(timeout=grace)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
        raise
    return subprocess.CompletedProcess(command, proc.returncode, out, err)
