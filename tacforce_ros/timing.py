"""Wall-time measurement shared by the benchmarks and the main job's timing stage."""
from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np


def time_interleaved(calls: dict[tuple[str, str], Callable[[], object]], repeats: int,
                     rounds: int = 10) -> dict[tuple[str, str], dict[str, float]]:
    """Median and p99 wall time [us] of each call, `repeats` calls each.

    The calls are timed round-robin in `rounds` slices, so on a shared machine every model sees
    the same background load and the ratios between models stay meaningful.
    """
    per_round = max(1, repeats // rounds)
    samples: dict[tuple[str, str], list[int]] = {key: [] for key in calls}
    for call in calls.values():
        for _ in range(50):         # warm-up: caches, lazy buffers
            call()
    for _ in range(rounds):
        for key, call in calls.items():
            record = samples[key].append
            for _ in range(per_round):
                start = time.perf_counter_ns()
                call()
                record(time.perf_counter_ns() - start)
    return {key: {'median_us': float(np.median(v) / 1e3),
                  'p99_us': float(np.percentile(v, 99) / 1e3)} for key, v in samples.items()}


def bare_mujoco_seconds(model, qpos: np.ndarray, steps: int) -> float:
    """Wall seconds of `steps` bare MuJoCo steps (mj_step) from `qpos`: the physics alone, against
    which the simulator's own cost, and a machine's speed, are read."""
    import mujoco
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    start = time.perf_counter()
    for _ in range(steps):
        mujoco.mj_step(model, data)
    return time.perf_counter() - start
