"""Support for integration tests: run session-plan nodes as real processes on a test's own DDS
domain and ports, and build a full-hand model set from synthetic data."""
from __future__ import annotations

import dataclasses
import os
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from tacforce_ros.estimation.model_io import save_model
from tacforce_ros.estimation.synthetic import synthetic_dataset
from tacforce_ros.estimation.training import fit_bundle
from tacforce_ros.hand.description import HandDescription
from tacforce_ros.nodes.session_plan import NodeLaunch, SessionArgs, plan
from tacforce_ros.tools.session import start_nodes, stop_nodes

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
        self.procs = start_nodes(nodes, log_dir, ready_timeout=30.0, env=ros_env(domain))
        assert len(self.procs) == len(nodes), self.logs()

    def alive(self) -> bool:
        return all(proc.poll() is None for _, proc in self.procs)

    def logs(self) -> str:
        return '\n'.join(f'--- {p.name}\n{p.read_text()[-1500:]}'
                         for p in sorted(self.log_dir.glob('*.log')))

    def stop(self) -> dict[str, int]:
        return stop_nodes(self.procs, grace=15.0)


def graph_nodes(args: SessionArgs) -> list[NodeLaunch]:
    return plan(args)


def synthetic_model_set(folder: Path, hand: HandDescription,
                        use: dict[str, Path] | None = None) -> Path:
    """A models YAML with an M3 model per array fitted on synthetic data (accuracy does not
    matter here, only that every array has a real model file); `use` replaces some."""
    folder.mkdir(parents=True, exist_ok=True)
    models = {}
    for k, array in enumerate(hand.arrays):
        if use and array.name in use:
            models[array.name] = str(use[array.name])
            continue
        data = synthetic_dataset(array, plates=('flat', 'button'), seconds=4.0, seed=k)
        rest = data.X[:20].mean(axis=0)
        provenance = {'dataset': ['synthetic'], 'plates': ['flat', 'button'],
                      'samples': int(data.X.shape[0]), 'date': 'test', 'seed': k,
                      'code_version': 'test', 'metrics': None}
        bundle = fit_bundle(array, 'M3', {}, data.X - rest, data.F, data.plates, x_offset=rest,
                            provenance=provenance)
        models[array.name] = save_model(folder / f'{array.name}_M3.npz', bundle).name
    path = folder / 'models.yaml'
    path.write_text(yaml.safe_dump({'models': models}))
    return path


def wait_until(done, timeout: float, spin=None) -> bool:
    deadline = time.monotonic() + timeout
    while not done() and time.monotonic() < deadline:
        spin() if spin is not None else time.sleep(0.05)
    return bool(done())


__all__ = ['Graph', 'free_ports', 'graph_nodes', 'np', 'session_args', 'synthetic_model_set',
           'unique_domain_id', 'wait_until', 'with_overrides']
