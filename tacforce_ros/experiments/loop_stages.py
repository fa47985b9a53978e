"""Stages of the main job that close the loop: the closed-loop runs (Table III), the low-passed
loop, and the same session through the ROS node graph against the in-process run.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from tacforce_ros.control.command_sequence import ForceSequence
from tacforce_ros.control.force_controller import shipped_params_file
from tacforce_ros.control.grasp import finger_configs
from tacforce_ros.estimation.causal_filter import BatchLowPass
from tacforce_ros.estimation.model_set import load_model_set
from tacforce_ros.rig import HELD_OUT_PLATE
from tacforce_ros.experiments import node_path
from tacforce_ros.experiments.cache import (digest, file_digest,
                                            node_modules, scene_digest, source_digest,
                                            tool_modules)
from tacforce_ros.experiments.closed_loop import run_closed_loop
from tacforce_ros.experiments.grasp import run_grasp
from tacforce_ros.hand.description import load_hand
from tacforce_ros.hand.kinematics import HandKinematics
from tacforce_ros.paths import config_dir
from tacforce_ros.sim import load_scene
from tacforce_ros.sim.scene import calibration_scene_name, session_seed
from tacforce_ros.experiments.estimation_stages import model_config_file
from tacforce_ros.experiments.settings import (GRASP_FINGERS, GRASP_MODEL, Context,
                                               controller_config, controllers_for,
                                               hand_digest, scene_for, tare_frames)
from tacforce_ros.experiments.workers import job_closed_loop, run_units, worker_hand


def closed_loop_seed(obj: str, repeat: int, base: int) -> int:
    """Repeat k of every controller on one object shares its seed (a paired comparison)."""
    return session_seed(base, 'closed_loop', obj, repeat)


def closed_loop_unit(ctx: Context, obj: str, controller: str, repeat: int, models: dict,
                     lowpass: tuple[float, int] | None = None) -> tuple[str, tuple | None]:
    """(trace path, job unit to run, or None when the cache has it) of one closed-loop run."""
    s = ctx.settings
    scene = scene_for(ctx, f'closed_loop_{obj}')
    code = source_digest(run_closed_loop, load_model_set, ForceSequence, load_hand, HandKinematics)
    inputs = file_digest(shipped_params_file(), config_dir() / 'commands' / f'{s.sequence}.yaml',
                         config_dir() / 'params' / 'estimator.yaml')
    model_config = None if controller == 'open_loop' else \
        model_config_file(ctx, controller, models)
    model_key = None if model_config is None else Path(models['index_tip'][controller]).stem
    seed = closed_loop_seed(obj, repeat, s.seed)
    key = digest({'scene': scene_digest(scene), 'seed': seed, 'model': model_key,
                  'controller': controller, 'rate': s.control_rate, 'code': code,
                  'inputs': inputs, 'hand': hand_digest(),
                  **({} if lowpass is None else {'lowpass': lowpass,
                                                 'filter_code': source_digest(BatchLowPass)})})
    target = ctx.cache.path('closed_loop', key, '.npz')
    if ctx.cache.lookup('closed_loop', key, '.npz') is not None:
        return str(target), None
    target.parent.mkdir(parents=True, exist_ok=True)
    return str(target), (str(target), job_closed_loop,
                         (scene, seed, controller,
                          None if model_config is None else str(model_config),
                          s.sequence, s.control_rate, str(target), lowpass))


def closed_loop_stage(ctx: Context, models: dict) -> dict[tuple[str, str], list[str]]:
    """Table III runs: {(object, controller): [trace paths]}."""
    s = ctx.settings
    jobs, traces = [], {}
    for obj in s.objects:
        for controller in controllers_for(obj):
            for repeat in range(s.repeats):
                path, job = closed_loop_unit(ctx, obj, controller, repeat, models)
                traces.setdefault((obj, controller), []).append(path)
                jobs += [job] if job is not None else []
    ctx.log(f'stage closed loop: {sum(map(len, traces.values()))} runs, {len(jobs)} to simulate')
    run_units(ctx, 'closed-loop runs', jobs)
    return traces


def filtered_closed_loop_stage(ctx: Context, models: dict, end_to_end: dict) -> dict:
    """The closed-loop effect of the input low-pass: M3-lambda on the spherical plate, the same
    repeats (seeds) as Table III's, with the estimator's input low-pass at the cut-off that gave
    M3-lambda the lowest e_hat of the cut-offs on the held-out session (`best_offline`: and
    lower than without a filter). Returns the cut-off, its group delay and the trace paths."""
    s = ctx.settings
    label = 'M3-lambda'
    mine = [r for r in end_to_end['rows'] if r['model'] == label]
    best = min((r for r in mine if r['cutoff_hz'] is not None), key=lambda r: r['e_hat_mean'])
    chosen = best['cutoff_hz']
    lowpass = (chosen, end_to_end['filter_order'])
    jobs, paths = [], []
    for repeat in range(s.repeats):
        path, job = closed_loop_unit(ctx, HELD_OUT_PLATE, label, repeat, models, lowpass)
        paths.append(path)
        jobs += [job] if job is not None else []
    ctx.log(f'stage filtered closed loop: {len(paths)} runs of {label} with a {chosen:g} Hz '
            f'input low-pass, {len(jobs)} to simulate')
    run_units(ctx, 'filtered closed-loop runs', jobs)
    unfiltered = next(r for r in mine if r['cutoff_hz'] is None)
    return {'controller': label, 'object': HELD_OUT_PLATE, 'cutoff_hz': chosen,
            'best_offline': best['e_hat_mean'] < unfiltered['e_hat_mean'],
            'group_delay_ms': best['group_delay_ms'], 'traces': paths}


def node_path_stage(ctx: Context, models: dict, grasp_models: Path) -> dict:
    """One calibration session, one closed-loop run (M3-lambda, spherical plate) and one grasp
    (the first grasp object at the first grip, the grasp's models `grasp_models`) through the
    node graph, each compared with the direct path on the same scene and seed. Cached like the
    other stages; a failure is recorded with its reason, never replaced by direct results."""
    s = ctx.settings
    if not s.node_path:
        return {'ran': False, 'reason': 'switched off for this run (--quick or --no-node-path)'}
    try:
        session_modules = tool_modules('session')
    except ValueError as exc:
        return {'ran': False, 'reason': f'session is not installed: {exc}'}
    hand, kinematics = worker_hand()
    calibration_scene = scene_for(ctx, calibration_scene_name('index_tip', HELD_OUT_PLATE))
    loop_scene = scene_for(ctx, 'closed_loop_spherical')
    grasp_object, grip = s.grasp_objects[0], s.grasp_grips[0]
    grasp_scene = scene_for(ctx, f'grasp_{grasp_object}')
    model = models['index_tip']['M3-lambda']
    key = digest({'scenes': [scene_digest(calibration_scene), scene_digest(loop_scene),
                             scene_digest(grasp_scene)],
                  'model': Path(model).stem, 'grasp_models': file_digest(grasp_models),
                  'grasp': [grasp_object, grip],
                  'code': source_digest(node_path.run_session, *session_modules,
                                        node_path.closed_loop_against_direct,
                                        node_path.grasp_against_direct,
                                        node_path.bag_check, run_closed_loop, run_grasp,
                                        *node_modules()),
                  'inputs': file_digest(*sorted((config_dir() / 'params').glob('*.yaml')),
                                        config_dir() / 'commands' / f'{s.sequence}.yaml')})
    cached = ctx.cache.load_json('node_path', key)
    if cached is not None:
        return cached
    work = ctx.cache.path('node_path', key, '.d')
    result: dict[str, Any] = {'ran': True, 'work_dir': str(work)}
    started = time.perf_counter()
    try:
        ctx.log(f'stage node path: calibration session ({node_path.CALIBRATION_SECONDS:g} s '
                'simulated)')
        bag = node_path.run_session('calibration', calibration_scene, HELD_OUT_PLATE,
                                    work / 'calibration', node_path.CALIBRATION_SECONDS,
                                    seed=load_scene(calibration_scene).seed)
        result['calibration'] = node_path.compare_calibration(
            bag, hand, kinematics, calibration_scene, load_scene(calibration_scene).seed, model,
            s.static_force)
        result['calibration']['exit_codes'] = node_path.session_exit_codes(work / 'calibration')
        sequence = ForceSequence.load(s.sequence)
        ctx.log(f'stage node path: closed-loop run ({sequence.duration:g} s + start-up, '
                'simulated)')
        result['closed_loop'], trace, direct, bag = node_path.closed_loop_against_direct(
            hand, kinematics, loop_scene, HELD_OUT_PLATE, load_scene(loop_scene).seed,
            model_config_file(ctx, 'M3-lambda', models), sequence, work / 'closed_loop',
            controller_config('M3-lambda'), tare_frames(), control_rate=s.control_rate)
        result['closed_loop_bag'] = node_path.bag_check(bag)
        np.savez(work / 'closed_loop_traces.npz',
                 **{f'node_{k}': v for k, v in trace.arrays().items()},
                 **{f'direct_{k}': v for k, v in direct.arrays().items()})
    except (node_path.NodePathUnavailable, OSError, ValueError) as exc:
        result.update(ran=False, reason=str(exc))
        ctx.log(f'stage node path: did not complete: {exc}')
        return result          # not cached: the next run tries again
    try:
        ctx.log(f'stage node path: grasp of the {grasp_object} at {grip:g} N '
                f'({load_scene(grasp_scene).duration:g} s simulated)')
        result['grasp'], grasp_trace, grasp_direct, bag = node_path.grasp_against_direct(
            hand, kinematics, grasp_scene, load_scene(grasp_scene).seed, grasp_models, grip,
            work / 'grasp', finger_configs(controller_config(GRASP_MODEL), hand, GRASP_FINGERS),
            tare_frames())
        result['grasp_bag'] = node_path.bag_check(bag)
        np.savez(work / 'grasp_traces.npz',
                 **{f'node_{k}': v for k, v in grasp_trace.arrays().items()},
                 **{f'direct_{k}': v for k, v in grasp_direct.arrays().items()})
    except (node_path.NodePathUnavailable, OSError, ValueError) as exc:
        # The sessions before it stand; the grasp's failure is reported with its reason.
        result['grasp'] = {'ran': False, 'reason': str(exc)}
        ctx.log(f'stage node path: the grasp did not complete: {exc}')
        return result          # not cached: the next run tries again
    ctx.timings['node path'] = time.perf_counter() - started
    ctx.cache.store_json('node_path', key, result)
    return result
