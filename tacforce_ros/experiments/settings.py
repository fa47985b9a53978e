"""The main job's settings and inputs: what a run computes (Settings), the arrays, plates,
objects and controllers of the paper's tables, the skin its scenes are on, and the project
files every stage reads (controller, estimator tare, models' hyperparameters).
"""
from __future__ import annotations

import dataclasses
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import yaml

from tacforce_ros.control.force_controller import ForceControllerConfig, shipped_params_file
from tacforce_ros.estimation.learning_curve import SECONDS as LEARNING_SECONDS
from tacforce_ros.estimation.registry import paper_configurations
from tacforce_ros.hand.description import KINDS
from tacforce_ros.recording.budget import MIN_SESSION_S
from tacforce_ros.rig import HELD_OUT_PLATE, RATE_HZ, TRAINING_PLATES
from tacforce_ros.experiments.cache import StageCache, atomic_write, file_digest
from tacforce_ros.bringup.session_plan import shipped_parameters
from tacforce_ros.paths import config_dir
from tacforce_ros.sim.effects.magnetic_skin import magnetic_skin_overlay

PLATES = TRAINING_PLATES
ARRAYS = ('index_tip', 'index_middle')                       # curved fingertip, flat phalanx
OBJECTS = ('spherical', 'foam_brick', 'softball', 'abrasive_sponge', 'bleach_cleanser')
CONTROLLERS = ('open_loop', 'M3-lambda', 'M4')               # Table III rows


def controllers_for(obj: str) -> tuple[str, ...]:
    """Paper Sec. IV-C: the open loop ran on the spherical plate only; the objects with the
    closed-loop controllers alone."""
    return CONTROLLERS if obj == HELD_OUT_PLATE else CONTROLLERS[1:]


ONLINE_MODELS = ('M3-lambda', 'M4')                          # Table II rows
# The grasp table: objects (config/scenes/grasp_<object>.yaml: a rigid and a soft sphere, a
# rigid cylinder, a soft box) x grip forces, the thumb and index fingertip pinching, the closed
# loop on M3-lambda against the open loop. The gelatin box's 97 g is refused at 1 N (the controller
# asks 1.19 N at its assumed friction), so it is not a row.
GRASP_OBJECTS = ('golf_ball', 'marker', 'tennis_ball', 'foam_brick')
GRASP_GRIPS = (1.0, 2.0)                                      # N
GRASP_FINGERS = ('thumb', 'index')
GRASP_MODEL = 'M3-lambda'
GRASP_CONTROLLERS = (GRASP_MODEL, 'open_loop')
# Fingertips of the grasp whose model comes from the whole-hand campaign (the index fingertip's
# is Table I's).
GRASP_ARRAYS = tuple(f'{f}_tip' for f in GRASP_FINGERS if f'{f}_tip' not in ARRAYS)
# The estimator's input low-pass settings compared end to end (None: off, the node's default).
FILTER_CUTOFFS_HZ = (None, 20.0, 10.0, 5.0)
NODE_LATENCY_SECONDS = 10.0      # bench_ros's latency test, frames at 100 Hz


# The main job's longer extensions, run on request (`reproduce --extended`, or named with
# `--stages`); the default run is the paper's experiments, the grasp and the node graph's check.
EXTENDED_STAGES = {
    'whole_hand': 'every other array pressed on the five training plates, M3-lambda '
                  'leave-one-plate-out per array (the whole-hand table, whole_hand.png)',
    'cross_array': "each array's M3-lambda on every other array of its kind, unadapted "
                   '(needs whole_hand)',
    'learning_curve': 'held-out e_hat against labelled seconds, own and shared models '
                      '(needs whole_hand)',
    'budget': 'a 60-minute campaign with the mirror hand pooled, against the full plan',
    'skin_sensitivity': "Table I with each of the magnetic skin's estimated parameters varied "
                        '(the skin_sensitivity tool)',
}
STAGE_NEEDS = {'cross_array': ('whole_hand',), 'learning_curve': ('whole_hand',)}


def with_needs(stages) -> tuple[str, ...]:
    """The stages and those they need, in EXTENDED_STAGES' order."""
    wanted = set(stages)
    for stage in stages:
        wanted.update(STAGE_NEEDS.get(stage, ()))
    unknown = sorted(wanted - set(EXTENDED_STAGES))
    if unknown:
        raise ValueError(f'unknown stage(s) {unknown}: one of {list(EXTENDED_STAGES)}')
    return tuple(s for s in EXTENDED_STAGES if s in wanted)


@dataclass(frozen=True)
class Settings:
    """Data sizes and choices of one run (the defaults are the full run)."""

    sessions_per_plate: int = 4          # paper: 4 x 100 s per plate and array
    session_seconds: float = 100.0
    online_seconds: float = 200.0        # paper: 200 s online on the spherical plate
    models: tuple[str, ...] = ('M1', 'M2', 'M3', 'M3-lambda', 'M3-lambda-cv', 'M4', 'M5')
    epochs: int = 40                     # M4/M5, as the paper
    timing_repeats: int = 2000
    objects: tuple[str, ...] = OBJECTS
    repeats: int = 5                     # paper: 5 runs per object and controller
    sequence: str = 'paper_70s'
    control_rate: float = RATE_HZ        # paper: control and estimation at the frame rate
    seed: int = 0
    # Static-segment force threshold for offsets [N], around the F/T's own no-contact reading
    # (estimation/preprocessing.py static_mask), so its un-zeroed bias does not matter.
    static_force: float = 0.3
    node_path: bool = True
    # The whole-hand campaign (every other array, M3-lambda): one session per training plate of
    # the paper's session length, a quarter of its data, for the budget (the Table I arrays
    # have the paper's sizes).
    whole_hand_seconds: float = 100.0
    skin: str = 'magnetic'               # SKINS: every scene of the run on this skin
    grasp_objects: tuple[str, ...] = GRASP_OBJECTS
    grasp_grips: tuple[float, ...] = GRASP_GRIPS
    grasp_repeats: int = 5               # seeds per object and grip (the 5)
    # Learning curves: labelled seconds per array (estimation/learning_curve.SECONDS; the
    # paper's campaign is the last, 2000 s) and the models drawn.
    learning_seconds: tuple[float, ...] = LEARNING_SECONDS
    learning_models: tuple[str, ...] = ('M3-lambda', 'M4')
    # The campaign with a budget (experiments/budget_stages.py): the full plan it is judged
    # against (`campaign plan`'s default sessions per plate, of session_seconds), the kind-curve
    # points it plans on (seconds per array), the budget, its shortest session, and the kinds
    # of array in it. budget_pool: the mirror hand (its own modules), calibrated before on the
    # full plan, whose arrays join each kind's shared model reflected (estimation/mirror.py);
    # '' for none.
    full_plan_sessions: int = 2
    budget_pool: str = 'left'
    budget_seconds: tuple[float, ...] = (100.0, 150.0, 250.0, 400.0, 600.0, 1000.0)
    budget_minutes: float = 60.0
    budget_min_session_s: float = MIN_SESSION_S
    budget_kinds: tuple[str, ...] = KINDS
    # The extensions this run adds (EXTENDED_STAGES); none by default. skin_sensitivity's
    # sessions are whole_hand_seconds long; sensitivity_variants False: its values alone.
    extended: tuple[str, ...] = ()
    sensitivity_variants: bool = True

    @classmethod
    def quick(cls) -> Settings:
        """Small sizes for tests: every stage runs, on less data and fewer runs."""
        return cls(sessions_per_plate=1, session_seconds=20.0, online_seconds=20.0, epochs=1,
                   timing_repeats=100, objects=('spherical',), repeats=1, node_path=False,
                   whole_hand_seconds=20.0, grasp_objects=('golf_ball',), grasp_grips=(1.0,),
                   grasp_repeats=1, learning_seconds=(25.0, 100.0), full_plan_sessions=1,
                   budget_seconds=(50.0, 100.0), budget_minutes=5.5,
                   budget_min_session_s=20.0, budget_kinds=('palm',),
                   sensitivity_variants=False)


# The simulated skin: the empirical response (sim/taxel_response.py) or the one computed from
# the taxel's physics (sim/effects/magnetic_skin.py, docs/SKIN_PHYSICS.md).
SKINS = ('empirical', 'magnetic')


@dataclass
class Context:
    """What every stage needs: settings, cache, output folder, pool and progress output."""

    settings: Settings
    out: Path
    cache: StageCache
    pool: ProcessPoolExecutor
    log: Callable[[str], None] = print
    timings: dict[str, float] = field(default_factory=dict)
    # Per pool stage (run_units' title): its units' count, their summed and their longest wall
    # time, each measured in its worker: what the stage would take on more cores.
    units: dict[str, dict] = field(default_factory=dict)


def scene_for(ctx: Context, name: str) -> str:
    """The scene `name` on the run's skin (skin_scene, files in <out>/scenes)."""
    return skin_scene(ctx.out / 'scenes', name, ctx.settings.skin)


def skin_scene(folder: Path, name: str, skin: str) -> str:
    """The scene `name` on `skin`: `name` itself on the empirical skin; on the magnetic skin, a
    scene file in `folder` that extends it, which the node graph's `session --scene` loads as
    the direct path does (and a user can launch)."""
    if skin == 'empirical':
        return name
    if skin != 'magnetic':
        raise ValueError(f'skin {skin!r}: one of {SKINS}')
    text = yaml.safe_dump({'extends': name, 'effects': magnetic_skin_overlay()}, sort_keys=False)
    return str(atomic_write(folder / f'{name}_{skin}.yaml', lambda tmp: tmp.write_text(text)))


WHOLE_HAND_MODEL = 'M3-lambda'
# The model a kind's arrays share and adapt (estimation/shared_model.py: a linear one).
SHARED_MODEL = 'M3-lambda'


def controller_config(controller: str):
    """The project's controller parameters; open loop is the same with K_i = 0 (paper)."""
    config = ForceControllerConfig.from_yaml(shipped_params_file())
    return dataclasses.replace(config, k_i=(0.0, 0.0, 0.0)) if controller == 'open_loop' \
        else config


def estimator_parameter(name: str):
    """A parameter of the estimator node as the project ships it (config/params/estimator.yaml)."""
    return shipped_parameters('estimator')[name]


def tare_frames() -> int:
    """Frames the estimator node tares on."""
    return int(estimator_parameter('tare_frames'))


def hand_digest() -> str:
    hand_dir = config_dir() / 'hand'
    return file_digest(*sorted(hand_dir.glob('*.yaml')),
                       *sorted((config_dir() / 'urdf').glob('*.urdf')))


def model_hyper(label: str, settings: Settings) -> tuple[str, dict]:
    return paper_configurations(settings.seed, settings.epochs)[label]
