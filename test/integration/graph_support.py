"""Support for integration tests: run session-plan nodes as real processes on a test's own DDS
domain and ports, and build a full-hand model set from synthetic data."""
from __future__ import annotations

import dataclasses
import os
import sys
import time
from pathlib import Path

from tacforce_ros.estimation.model_set import write_synthetic_model_set as synthetic_model_set
from tacforce_ros.bringup.session_plan import NodeLaunch, SessionArgs, plan
from tacforce_ros.bringup.processes import start_nodes, stop_nodes

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import ros_env, unique_domain_id  # noqa: E402,F401


def free_ports(offset: int) -> tuple[int, int, int]:
    """Three ports for the emulators, distinct per test process and module."""
    base = 20000 + (os.getpid() % 2000) * 15 + 3 * offset
    return base, base + 1, base + 2


def session_args(mode: str, offset: int, **kwargs) -> SessionArgs:
    xela, netft, can = free_ports(offset)
    return SessionArgs(mode=mode, xela_port=xela, netft_port=netft, can_port=can, **kwargs)


def with_overrides(nodes: list[NodeLaunch], **per_node: dict) -> list[NodeLaunch]:
    return [dataclasses.replace(n, overrides={**n.overrides, **per_node.get(n.executable, {})})
            for n in nodes]


class Graph:
    """The nodes of a plan as processes; stop() SIGINTs them and returns their exit codes."""

    def __init__(self, nodes: list[NodeLaunch], domain: int, log_dir: Path) -> None:
        self.log_dir = log_dir
        self.procs = start_nodes(nodes, log_dir, env=ros_env(domain))

    def alive(self) -> bool:
        return all(proc.poll() is None for _, proc in self.procs)

    def logs(self) -> str:
        return '\n'.join(f'--- {p.name}\n{p.read_text()[-1500:]}'
                         for p in sorted(self.log_dir.glob('*.log')))

    def stop(self) -> dict[str, int]:
        return stop_nodes(self.procs, grace=15.0)


def graph_nodes(args: SessionArgs) -> list[NodeLaunch]:
    return plan(args)


def wait_until(done, timeout: float, spin=None) -> bool:
    deadline = time.monotonic() + timeout
    while not done() and time.monotonic() < deadline:
        spin() if spin is not None else time.sleep(0.05)
    return bool(done())


def wait_while_progressing(done, progress, stalled_after: float, timeout: float, spin) -> bool:
    """Spin until done(), for as long as progress() keeps changing: a run on a slow machine
    gets the time it needs (up to `timeout`), one that stopped fails after `stalled_after`."""
    deadline = time.monotonic() + timeout
    last, changed = progress(), time.monotonic()
    while (not done() and time.monotonic() < deadline
           and time.monotonic() - changed < stalled_after):
        spin()
        if (now := progress()) != last:
            last, changed = now, time.monotonic()
    return bool(done())


__all__ = ['Graph', 'free_ports', 'graph_nodes', 'session_args', 'synthetic_model_set',
           'unique_domain_id', 'wait_until', 'wait_while_progressing', 'with_overrides']
