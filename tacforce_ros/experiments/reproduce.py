"""reproduce: the paper's experiments end to end on the simulated hand, with a report.

Records calibration sessions (five training plates; index_tip and index_middle), runs the
leave-one-plate-out benchmark of M1-M5 and M3-lambda (Table I), retrains on all five plates and
tests online on the held-out spherical plate (Table II), runs the closed-loop experiments
(open loop, M3-lambda, M4; spherical plate and four soft objects; Table III), holds objects
between the thumb and index fingertip (the grasp table, not in the paper), sends one
calibration session and one closed-loop run through the ROS node graph (`session`) and compares
them with the direct path, and writes <out>/report.md, report.json and PNG figures.

Every stage is cached under <out>/cache by a hash of its inputs: re-running reuses what is
already computed, and a changed scene, parameter file or source file recomputes only what
depends on it.

    reproduce                 # the full run into out/
    reproduce --quick --out /tmp/r    # small sizes (tests), no node path
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import multiprocessing
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from tacforce_ros import results
from tacforce_ros.bringup.processes import interrupt_on_sigterm
from tacforce_ros.experiments import budget_stages as budget
from tacforce_ros.experiments import calibration_stages as calibration
from tacforce_ros.experiments import grasp_stages as grasp
from tacforce_ros.experiments import estimation_stages as estimation
from tacforce_ros.experiments import loop_stages as loop
from tacforce_ros.experiments import report
from tacforce_ros.experiments.settings import (CONTROLLERS, EXTENDED_STAGES, GRASP_MODEL, PLATES,
                                               SKINS, WHOLE_HAND_MODEL, Context, Settings,
                                               with_needs)
from tacforce_ros.experiments.workers import init_worker, load_trace, predicted_seconds
from tacforce_ros.rig import HELD_OUT_PLATE
from tacforce_ros.experiments.cache import StageCache
from tacforce_ros.experiments.node_path import AGREEMENT_N, AGREEMENT_REASON
from tacforce_ros.paths import output_folder

DEFAULT_OUT = Path(__file__).resolve().parents[2] / 'out'
PREDICTED_WORKERS = (1, 2, 4, 8, 16)     # the report's wall-time predictions, by worker count

PATHS = [
    'Direct path (core objects composed in-process, faster than real time): every calibration '
    'session, Table I, Table II and every Table III run; a tick\'s torque reaches the simulated '
    'hand one control period after the state it was computed from (actuation_delay).',
    'Node graph (`session` tool: sim_world + emulators + drivers + recorder / estimator / '
    'controller over DDS, in simulated time): one calibration session on the spherical plate and '
    'one closed-loop run (M3λ, spherical plate), compared below with the direct path on the same '
    'scene and seed.',
    'Tare: closed-loop runs start with the fingertip clear of the plate; the direct path holds '
    'that start pose 2 s and zeroes the F/T sensor and tares the estimator on its last 50 '
    'frames, out of contact; the estimator node tares on its first 50 frames at start-up '
    '(estimator.yaml tare_at_start) while the driver holds the start pose; the node run\'s '
    'f_d, f_hat and F/T come from its bag (F/T zeroed before the first command).',
]
NODE_TOLERANCE_REASON = (
    f"{AGREEMENT_N['calibration_e_hat']} N on e_hat, {AGREEMENT_N['closed_loop_e_tilde']} N on "
    f"e~ and {AGREEMENT_N['closed_loop_e_track']} N on e_track. {AGREEMENT_REASON}")


def figures(out: Path, cv: dict, table_i: dict, end_to_end: dict, traces: dict,
            whole_hand: dict | None, learning: list[dict]) -> list[str]:
    from tacforce_ros.experiments import plots
    from tacforce_ros.hand.description import load_hand
    from tacforce_ros.hand.figure import hand_errors
    from tacforce_ros.estimation.learning_curve import plot_curves
    names = [plots.accuracy_vs_time(table_i, end_to_end, out / 'accuracy_vs_time.png').name]
    if learning:
        names.append(plot_curves(learning, out / 'learning_curve.png',
                                 'SIMULATION: held-out e_hat against labelled seconds').name)
    names.append(plots.per_plate_errors(cv, out / 'per_plate_errors.png').name)
    if whole_hand:
        names.append(hand_errors(load_hand(),
                                 {a: row['cv']['e_hat_mean'] for a, row in whole_hand.items()},
                                 f'SIMULATION, {WHOLE_HAND_MODEL}: held-out e_hat [N]',
                                 out / 'whole_hand.png').name)
    by_object: dict[str, dict] = {}
    for (obj, controller), paths in traces.items():
        by_object.setdefault(obj, {})[controller] = [load_trace(p) for p in paths]
    for obj, runs in by_object.items():
        names.append(plots.tracking(runs, f'force tracking, {obj}',
                                    out / f'tracking_{obj}.png').name)
    return names


@contextlib.contextmanager
def workers(jobs: int):
    """The stages' worker processes; stopped at once if the job is (SIGINT, or SIGTERM taken as
    one), where leaving the `with` would wait for each one's current stage."""
    pool = ProcessPoolExecutor(max_workers=jobs, initializer=init_worker)
    try:
        yield pool
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        for child in multiprocessing.active_children():
            child.terminate()
        raise
    pool.shutdown()


def shipped_models(folder: Path) -> list[dict]:
    """Each model the job's model lists (`out/models/*.yaml`) ship: which way it was made and
    with how many seconds of its own array's data, from its provenance."""
    from tacforce_ros.estimation.model_io import read_header
    from tacforce_ros.estimation.model_set import model_files
    rows = []
    for config in sorted(folder.glob('*.yaml')):
        for array, path in model_files(config).items():
            header = read_header(path)
            made = header['provenance']
            rows.append({'set': f'models/{config.name}', 'array': array, 'kind': header['kind'],
                         'way': made.get('way'), 'own_seconds': made.get('own_seconds'),
                         'shared_from': made.get('shared_from', [])})
    return rows


def physics_step_us(steps: int = 2000, repeats: int = 3) -> float:
    """Wall us of one bare MuJoCo step of the closed-loop hand model, best of `repeats`: how
    fast the machine ran at the start and end of a run, so wall times taken on a shared machine
    can be compared (bench_sim sets the simulator's step against the same bare step)."""
    from tacforce_ros.hand.description import load_hand
    from tacforce_ros.sim import load_scene, make_simulator
    from tacforce_ros.timing import bare_mujoco_seconds
    sim = make_simulator(load_scene('closed_loop_spherical'), load_hand(), seed=0)
    best = min(bare_mujoco_seconds(sim.model, sim.data.qpos, steps) for _ in range(repeats))
    return 1e6 * best / steps


def skin_sensitivity_stage(ctx: Context, jobs: int) -> dict:
    """The skin_sensitivity tool on the run's session length, epochs and seed into
    <out>/skin_sensitivity/ (without sensitivity_variants: the values alone, no closed loop);
    returns the targets it judged and where its tables are."""
    from tacforce_ros.experiments import skin_sensitivity
    s = ctx.settings
    folder = ctx.out / 'skin_sensitivity'
    folder.mkdir(parents=True, exist_ok=True)
    args = ['--out', str(folder), '--jobs', str(jobs), '--seeds', str(s.seed),
            '--seconds', f'{s.whole_hand_seconds:g}', '--epochs', str(s.epochs)]
    if not s.sensitivity_variants:
        args += ['--params', '--closed-loop']
    ctx.log('stage skin sensitivity: ' + ' '.join(args))
    started = time.perf_counter()
    with contextlib.redirect_stdout(sys.stderr):
        skin_sensitivity.main(args)
    ctx.timings['skin sensitivity'] = time.perf_counter() - started
    result = json.loads((folder / 'skin_sensitivity.json').read_text())
    return {'files': ['skin_sensitivity/skin_sensitivity.md',
                      'skin_sensitivity/skin_sensitivity.json'],
            'targets': result['targets']}


def run(settings: Settings, out: Path, jobs: int) -> dict:
    from tacforce_ros.experiments.closed_loop import trace_metrics
    started = time.perf_counter()
    load_before = os.getloadavg()
    step_before = physics_step_us()
    cache = StageCache(out / 'cache')
    extended = set(settings.extended)
    whole_hand = cross_array = budget_campaign = sensitivity = None
    learning: list[dict] = []
    with workers(jobs) as pool:
        ctx = Context(settings=settings, out=out, cache=cache, pool=pool,
                               log=lambda line: print(line, file=sys.stderr, flush=True))
        layout = calibration.calibration_stage(ctx)
        cv, models = calibration.benchmark_stage(ctx, layout)
        grasp_cv, grasp_arrays, grasp_sets = calibration.grasp_arrays_stage(ctx)
        if 'learning_curve' in extended:
            learning = calibration.learning_curve_stage(ctx, layout)
        if 'whole_hand' in extended:
            whole_hand, sets = calibration.whole_hand_stage(ctx, cv, layout, grasp_cv,
                                                            grasp_sets)
            if 'cross_array' in extended:
                cross_array = calibration.cross_array_stage(ctx, sets, whole_hand)
            if 'learning_curve' in extended:
                learning += calibration.shared_curve_stage(ctx, layout, sets)
        if 'budget' in extended:
            budget_campaign = budget.budget_stage(ctx)
        timing = estimation.timing_stage(ctx, models)
        online = estimation.online_stage(ctx, layout, models)
        end_to_end = estimation.end_to_end_stage(ctx, layout, models, timing,
                                               estimation.node_latency_stage(ctx))
        traces = loop.closed_loop_stage(ctx, models)
        plain = traces.get((HELD_OUT_PLATE, 'M3-lambda'))
        filtered = None if plain is None else \
            loop.filtered_closed_loop_stage(ctx, models, end_to_end)
        grasp_models = grasp.grasp_model_config(ctx, models, grasp_arrays)
        grasp_traces = grasp.grasp_stage(ctx, grasp_models)
    node = loop.node_path_stage(ctx, models, grasp_models)
    if 'skin_sensitivity' in extended:
        sensitivity = skin_sensitivity_stage(ctx, jobs)
    closed = {key: trace_metrics([load_trace(p) for p in paths])
              for key, paths in traces.items()}
    filter_effect = None if filtered is None else report.filter_closed_loop(
        filtered, closed[(HELD_OUT_PLATE, 'M3-lambda')],
        trace_metrics([load_trace(p) for p in filtered['traces']]))
    rows = report.table_iii(closed)
    table_i = report.table_i(cv, timing)
    single = closed.get((HELD_OUT_PLATE, GRASP_MODEL))
    grasp_rows = grasp.grasp_rows(grasp_traces, None if single is None else
                                  single['e_tilde_mean'])
    doc = {
        'label': 'SIMULATION: every sim number comes from the simulated hand, not hardware',
        'skin': settings.skin,
        'settings': dataclasses.asdict(settings), 'plates': list(PLATES),
        'controllers': list(CONTROLLERS), 'paths': PATHS,
        'table_I': table_i, 'online': online,
        'table_II': report.table_ii(online), 'end_to_end': end_to_end, 'table_III': rows,
        'filter_closed_loop': filter_effect,
        'must_show': report.must_show(rows), 'node_path': node, 'whole_hand': whole_hand,
        'skin_targets': (report.skin_targets(table_i, rows, settings.seed)
                         if settings.skin == 'magnetic' else None),
        'node_tolerance_reason': NODE_TOLERANCE_REASON,
        'grasp': {'rows': grasp_rows, 'must_show': grasp.grasp_must_show(grasp_rows),
                  'hand_over_s': grasp.hand_over_after_goal(settings.grasp_objects[0])},
        'learning_curve': {'rows': learning} if learning else None,
        'shipped_models': shipped_models(out / 'models'),
        'cross_array': cross_array,
        'budget_campaign': budget_campaign,
        'skin_sensitivity': sensitivity,
        'figures': (figures(out, cv, table_i, end_to_end, traces, whole_hand, learning)
                    + grasp.grasp_figures(grasp_traces, out)),
    }
    # What differs between two runs of the same inputs lives under 'run' only.
    wall = time.perf_counter() - started
    doc['run'] = {'date': time.strftime('%Y-%m-%dT%H:%M:%S%z'), 'code_version': results.commit(),
                  'wall_seconds': wall, 'stage_seconds': ctx.timings, 'stage_units': ctx.units,
                  'predicted_seconds': {str(n): predicted_seconds(ctx.timings, ctx.units, wall, n)
                                        for n in PREDICTED_WORKERS},
                  'cache': {'hits': cache.hits, 'misses': cache.misses},
                  'machine': {'cpus': os.cpu_count(), 'jobs': jobs, 'load_before': load_before,
                              'load_after': os.getloadavg(),
                              'mujoco_step_us': [step_before, physics_step_us()]}}
    return doc


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='reproduce', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--out', type=output_folder, default=str(DEFAULT_OUT),
                        help=f'output folder (default {DEFAULT_OUT})')
    parser.add_argument('--quick', action='store_true',
                        help='small sizes: 1 x 20 s session per plate, 1 epoch, the spherical '
                             'plate with 1 run per controller, no node path (~2 min)')
    parser.add_argument('--no-node-path', action='store_true',
                        help='skip the node-graph session and run (the report says so)')
    parser.add_argument('--node-path', action='store_true',
                        help='run the node-graph session and run even with --quick')
    parser.add_argument('--extended', action='store_true',
                        help='add every longer extension: ' + ', '.join(EXTENDED_STAGES))
    parser.add_argument('--stages', nargs='+', default=[], metavar='STAGE',
                        choices=list(EXTENDED_STAGES),
                        help='add these extensions (and those they need): '
                             + '; '.join(f'{k}: {v}' for k, v in EXTENDED_STAGES.items()))
    parser.add_argument('--workers', '--jobs', dest='jobs', type=int,
                        default=os.cpu_count() or 1,
                        help=f'worker processes (default: the cores, {os.cpu_count()} here)')
    parser.add_argument('--seed', type=int, default=0, help='base seed of sessions and runs')
    parser.add_argument('--skin', choices=SKINS, default=Settings.skin,
                        help='the simulated skin of every scene: magnetic (default), computed '
                             'from the taxel\'s physics (docs/SKIN_PHYSICS.md; the report judges '
                             'its targets), or empirical, the fitted response (faster)')
    args = parser.parse_args(argv)
    interrupt_on_sigterm()      # its finally blocks stop the processes it started
    if args.jobs < 1:
        parser.error('--jobs must be >= 1')
    settings = Settings.quick() if args.quick else Settings()
    settings = dataclasses.replace(settings, seed=args.seed, skin=args.skin,
                                   node_path=(settings.node_path or args.node_path)
                                   and not args.no_node_path,
                                   extended=with_needs(EXTENDED_STAGES if args.extended
                                                       else args.stages))
    doc = run(settings, args.out, args.jobs)
    (args.out / 'report.json').write_text(json.dumps(doc, indent=1, default=str))
    text = report.markdown(doc)
    (args.out / 'report.md').write_text(text)
    print(text)
    print(f"wrote {args.out / 'report.md'}, report.json and {len(doc['figures'])} figures "
          f"in {doc['run']['wall_seconds']:.0f} s", file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
