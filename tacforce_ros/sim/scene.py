"""Scenes: what a simulation run contains, loaded from YAML under config/scenes/.

A scene file may name another with `extends: <stem>`; the two are deep-merged (the child wins,
and `null` deletes an inherited key, e.g. `effects: {noise: null}` switches one effect off).
Files whose stem starts with `_` hold shared defaults and are not scenes on their own.

A calibration scene needs no file: `calibration_<array>_<plate>` is `_calibration` with that
array and plate (any array of the hand, any plate of the plates library), so a campaign over
all 18 arrays has one home for what a calibration session is. Likewise a closed-loop scene
`closed_loop_<fingertip>_<object>` is `closed_loop_<object>` (the index finger's) with that
fingertip pressing instead (and `_closed_loop_<finger>.yaml`'s finger part, where the finger has
one: the thumb). A file of either name wins.

A grasp scene (kind `grasp`, sim/grasp.py) has fingers pinching a free object of the
`grasp_objects` library instead of a plate: each fingertip's contact surface is the object's.
"""
from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from tacforce_ros.paths import config_dir
from tacforce_ros.rig import FINGERS

KINDS = ('calibration', 'closed_loop', 'grasp')
FINGER_FIELDS = {'pose': 4, 'others': 12, 'others_kp': 0, 'others_kd': 0, 'tip_radius': 0,
                 'skin_stiffness': 0, 'skin_damping': 0}   # closed loop; value = list length
OPTIONAL_FINGER_FIELDS = {'contact_pose': 4}   # default: `pose` (the finger starts in contact)
PLATE_SHAPES = ('sphere', 'cylinder', 'plane')
OBJECT_SHAPES = {'sphere': 1, 'box': 3, 'cylinder': 2}   # shape -> numbers in `size`


class SceneError(ValueError):
    """A scene file that is missing or malformed; the message names the offending field."""


@dataclass(frozen=True)
class Plate:
    """A 3D-printed push-plate indenter, described by its contact surface near the contact."""
    name: str
    shape: str          # sphere | cylinder (axis in the contact plane) | plane
    radius: float       # m; curvature radius (ignored for plane)


@dataclass(frozen=True)
class SoftObject:
    """A compliant object between fingertip and F/T sensor (closed-loop scenes)."""
    name: str
    stiffness: float    # N/m, through the object's thickness
    damping: float      # N s/m
    mass: float         # kg
    thickness: float    # m


@dataclass(frozen=True)
class GraspObject:
    """A free object to hold (grasp scenes), in its own frame: x across the grip (from the
    other fingers to the thumb), z the hand's up (against gravity), y = z x x."""
    name: str
    shape: str                  # sphere | box | cylinder (axis along z)
    size: tuple[float, ...]     # m: sphere (radius,), box half extents (x, y, z),
    #                             cylinder (radius, half length)
    mass: float                 # kg
    friction: float             # Coulomb coefficient, skin on the object's surface
    stiffness: float | None     # N/m through the surface at one contact; None: rigid
    damping: float              # N s/m, with the stiffness
    source: str                 # where size and mass come from

    @property
    def width(self) -> float:
        """m, across the grip (along x)."""
        return 2.0 * self.size[0]

    @property
    def plate(self) -> Plate:
        """The object's surface near a fingertip, as the skin models take an indenter: a box's
        face is a plane, a cylinder's side a cylinder (axis in the contact plane)."""
        shape = {'sphere': 'sphere', 'box': 'plane', 'cylinder': 'cylinder'}[self.shape]
        return Plate(name=self.name, shape=shape,
                     radius=0.0 if shape == 'plane' else self.size[0])


@dataclass(frozen=True)
class Scene:
    name: str
    kind: str                       # 'calibration' | 'closed_loop'
    array: str                      # contacted taxel array, e.g. index_tip
    plate: Plate
    duration: float                 # s
    tactile_rate: float             # Hz (uSkin: 100)
    physics_rate: float             # Hz; calibration scenes: = tactile_rate
    seed: int                       # session: noise, drift, operator, transport
    effects: dict[str, dict[str, Any]]   # enabled effects, in YAML order, with their parameters
    operator: dict[str, Any] = field(default_factory=dict)   # calibration: operator model
    finger: dict[str, Any] = field(default_factory=dict)     # closed loop: pose, tip geometry
    soft_object: SoftObject | None = None
    path: Path | None = None
    # The physical hand: per-taxel gains, baselines, coupling, actuator and link tolerances.
    # One hand is one sensor_seed, shared by every scene unless a scene names another.
    sensor_seed: int = 0
    # Calibration: arrays the operator presses in turn, `duration` each, round and round (a
    # press tour, sim/calibration.py); empty: `array` alone. `array` is the tour's first.
    press_tour: tuple[str, ...] = ()
    # Grasp: the object held and the fingers holding it (`grasp` mapping of the scene file:
    # fingers with their start and contact poses, gravity, hand-over, disturbances).
    grasp_object: GraspObject | None = None
    grasp: dict[str, Any] = field(default_factory=dict)

    @property
    def dt(self) -> float:
        return 1.0 / self.physics_rate


def scenes_dir() -> Path:
    return config_dir() / 'scenes'


CALIBRATION_PREFIX = 'calibration_'
CALIBRATION_DEFAULTS = '_calibration'
CLOSED_LOOP_PREFIX = 'closed_loop_'
CLOSED_LOOP_FINGER = 'index'        # the finger of the closed_loop_<object> scene files
CLOSED_LOOP_FINGERS = FINGERS      # every finger has its closed-loop scene


def list_scenes() -> list[str]:
    """The scene files; calibration scenes are also named without one (calibration_scene_name)."""
    return sorted(p.stem for p in scenes_dir().glob('*.yaml') if not p.stem.startswith('_'))


def calibration_scene_name(array: str, plate: str) -> str:
    return f'{CALIBRATION_PREFIX}{array}_{plate}'


def closed_loop_scene_name(array: str, plate: str) -> str:
    """The closed-loop scene of a fingertip pressing a plate or object (a closed_loop_* stem)."""
    if array == f'{CLOSED_LOOP_FINGER}_tip':
        return f'{CLOSED_LOOP_PREFIX}{plate}'
    return f'{CLOSED_LOOP_PREFIX}{array}_{plate}'


def _generated_scene(path: Path) -> dict | None:
    """A scene named as the module docstring says, under scenes_dir() without a file (load_scene
    checks the plate; the simulator the array); None for any other name."""
    stem = path.stem
    if path.parent != scenes_dir():
        return None
    if stem.startswith(CALIBRATION_PREFIX):
        array, _, plate = stem[len(CALIBRATION_PREFIX):].rpartition('_')
        return {'extends': CALIBRATION_DEFAULTS, 'array': array, 'plate': plate} if array else None
    finger, tip, scene = stem[len(CLOSED_LOOP_PREFIX):].partition('_tip_')
    if not stem.startswith(CLOSED_LOOP_PREFIX) or not tip:
        return None
    base = scenes_dir() / f'{CLOSED_LOOP_PREFIX}{scene}.yaml'
    if finger not in CLOSED_LOOP_FINGERS or not base.is_file():
        return None
    # A finger whose links or pose differ from the index finger's has its own part.
    own = scenes_dir() / f'_{CLOSED_LOOP_PREFIX}{finger}.yaml'
    part = (_read_yaml(own).get('finger') or {}) if own.is_file() else {}
    return {'extends': base.stem, 'array': f'{finger}_tip', 'finger': {**part, 'name': finger}}


def _deep_merge(base: dict, child: dict) -> dict:
    merged = dict(base)
    for key, value in child.items():
        if value is None:
            merged.pop(key, None)
        elif isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _deep_merge(merged[key], value)
        else:
            merged[key] = value
    return merged


def _resolve_path(name_or_path: str | Path) -> Path:
    path = Path(name_or_path)
    if path.suffix in ('.yaml', '.yml'):
        return path
    return scenes_dir() / f'{name_or_path}.yaml'


def _read_yaml(path: Path) -> dict:
    if not path.is_file():
        known = ', '.join(list_scenes()) if scenes_dir().is_dir() else 'none'
        raise SceneError(f'scene file {path} not found (known scenes: {known}; and '
                         f'{calibration_scene_name("<array>", "<plate>")} for any array and '
                         f'plate, {closed_loop_scene_name("<finger>_tip", "<object>")} for a '
                         'closed_loop_<object> scene pressed by another fingertip)')
    try:
        return yaml.safe_load(path.read_text(encoding='utf8')) or {}
    except yaml.YAMLError as exc:
        raise SceneError(f'{path}: not valid YAML: {exc}') from exc


def _load_raw(path: Path, chain: tuple[Path, ...] = ()) -> dict:
    if path in chain:
        raise SceneError(f'{path}: field "extends" forms a cycle ({" -> ".join(map(str, chain))})')
    raw = None if path.is_file() else _generated_scene(path)
    if raw is None:
        raw = _read_yaml(path)
    if not isinstance(raw, dict):
        raise SceneError(f'{path}: top level must be a mapping')
    parent = raw.pop('extends', None)
    if parent is None:
        return raw
    if not isinstance(parent, str):
        raise SceneError(f'{path}: field "extends" must be a scene file stem')
    # A parent next to the file wins; else the shared scenes folder (so a scene kept elsewhere
    # can still extend the project defaults).
    parent_path = path.parent / f'{parent}.yaml'
    if not parent_path.is_file():
        parent_path = scenes_dir() / f'{parent}.yaml'
    return _deep_merge(_load_raw(parent_path, chain + (path,)), raw)


def _get(raw: dict, key: str, kind: type, where: str) -> Any:
    if key not in raw:
        raise SceneError(f'{where}: missing field "{key}"')
    value = raw[key]
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
        raise SceneError(f'{where}: field "{key}" must be {kind.__name__}, got {value!r}')
    return value


def _positive(raw: dict, key: str, where: str) -> float:
    value = _get(raw, key, float, where)
    if not value > 0.0:
        raise SceneError(f'{where}: field "{key}" must be > 0, got {value}')
    return value


def _plate(raw: dict, where: str) -> Plate:
    name = _get(raw, 'plate', str, where)
    library = _get(raw, 'plates', dict, where)
    if name not in library:
        raise SceneError(f'{where}: field "plate" is {name!r}, not one of {sorted(library)}')
    spec = library[name]
    shape = _get(spec, 'shape', str, f'{where}: plates.{name}')
    if shape not in PLATE_SHAPES:
        raise SceneError(f'{where}: field "plates.{name}.shape" must be one of {PLATE_SHAPES}')
    radius = _positive(spec, 'radius', f'{where}: plates.{name}') if shape != 'plane' else 0.0
    return Plate(name=name, shape=shape, radius=radius)


def _soft_object(raw: dict, where: str) -> SoftObject | None:
    name = raw.get('object')
    if name is None:
        return None
    library = _get(raw, 'objects', dict, where)
    if name not in library:
        raise SceneError(f'{where}: field "object" is {name!r}, not one of {sorted(library)}')
    spec, sub = library[name], f'{where}: objects.{name}'
    return SoftObject(name=name, stiffness=_positive(spec, 'stiffness', sub),
                      damping=_get(spec, 'damping', float, sub), mass=_positive(spec, 'mass', sub),
                      thickness=_positive(spec, 'thickness', sub))


def _effects(raw: dict, where: str) -> dict[str, dict[str, Any]]:
    from tacforce_ros.sim.effects import EFFECTS   # the registry validates names and parameters
    effects = raw.get('effects') or {}
    if not isinstance(effects, dict):
        raise SceneError(f'{where}: field "effects" must be a mapping name -> parameters')
    result = {}
    for name, params in effects.items():
        if name not in EFFECTS:
            raise SceneError(f'{where}: field "effects.{name}": unknown effect '
                             f'(known: {sorted(EFFECTS)})')
        params = {} if params is True else params
        if params is False:
            continue
        if not isinstance(params, dict):
            raise SceneError(f'{where}: field "effects.{name}" must be a mapping of parameters')
        try:
            EFFECTS[name](**params)
        except (TypeError, ValueError) as exc:
            raise SceneError(f'{where}: field "effects.{name}": {exc}') from exc
        result[name] = dict(params)
    return result


def _finger(raw: dict, where: str) -> dict[str, Any]:
    finger = _get(raw, 'finger', dict, where)
    fields = {**FINGER_FIELDS, **{k: n for k, n in OPTIONAL_FINGER_FIELDS.items() if k in finger}}
    for key, length in fields.items():
        sub = f'{where}: finger'
        if length:
            value = _get(finger, key, list, sub)
            if len(value) != length or not all(isinstance(v, (int, float)) for v in value):
                raise SceneError(f'{sub}: field "finger.{key}" must be {length} numbers')
        else:
            _get(finger, key, float, sub)
    return finger


def load_scene(name_or_path: str | Path) -> Scene:
    """Load a scene by file stem under config/scenes/ or by path to a YAML file."""
    path = _resolve_path(name_or_path)
    raw = _load_raw(path)
    where = str(path)
    kind = _get(raw, 'kind', str, where)
    if kind not in KINDS:
        raise SceneError(f'{where}: field "kind" must be one of {KINDS}, got {kind!r}')
    tactile_rate = _positive(raw, 'tactile_rate', where)
    dynamic = kind in ('closed_loop', 'grasp')    # MuJoCo: a physics rate of their own
    physics_rate = _positive(raw, 'physics_rate', where) if dynamic else tactile_rate
    if dynamic and abs(physics_rate / tactile_rate
                                     - round(physics_rate / tactile_rate)) > 1e-9:
        raise SceneError(f'{where}: field "physics_rate" must be a multiple of tactile_rate')
    seed = _get(raw, 'seed', int, where)
    press_tour = _press_tour(raw, where) if kind == 'calibration' else ()
    if press_tour:
        raw.setdefault('array', press_tour[0])
        if raw['array'] != press_tour[0]:
            raise SceneError(f'{where}: field "array" must be the first of "press_tour"')
    sensor_seed = _get(raw, 'sensor_seed', int, where) if 'sensor_seed' in raw else 0
    grasp_object, grasp = (_grasp_object(raw, where), _grasp(raw, where)) if kind == 'grasp' \
        else (None, {})
    if grasp:       # the first finger's tip is the scene's array; the object is its plate
        raw['array'] = f'{next(iter(grasp["fingers"]))}_tip'
    return Scene(
        name=path.stem, kind=kind, array=_get(raw, 'array', str, where),
        plate=grasp_object.plate if grasp_object else _plate(raw, where),
        duration=_positive(raw, 'duration', where),
        tactile_rate=tactile_rate, physics_rate=physics_rate, seed=seed,
        effects=_effects(raw, where),
        operator=_get(raw, 'operator', dict, where) if kind == 'calibration' else {},
        finger=_finger(raw, where) if kind == 'closed_loop' else {},
        soft_object=_soft_object(raw, where), path=path, sensor_seed=sensor_seed,
        press_tour=press_tour, grasp_object=grasp_object, grasp=grasp)


def _grasp_object(raw: dict, where: str) -> GraspObject:
    name = _get(raw, 'grasp_object', str, where)
    library = _get(raw, 'grasp_objects', dict, where)
    if name not in library:
        raise SceneError(f'{where}: field "grasp_object" is {name!r}, not one of '
                         f'{sorted(library)}')
    spec, sub = library[name], f'{where}: grasp_objects.{name}'
    shape = _get(spec, 'shape', str, sub)
    if shape not in OBJECT_SHAPES:
        raise SceneError(f'{sub}: field "shape" must be one of {sorted(OBJECT_SHAPES)}')
    size = _get(spec, 'size', list, sub)
    if len(size) != OBJECT_SHAPES[shape] or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0 for v in size):
        raise SceneError(f'{sub}: field "size" must be {OBJECT_SHAPES[shape]} positive numbers '
                         f'(m) for a {shape}')
    stiffness = spec.get('stiffness')
    if stiffness is not None:
        stiffness = _positive(spec, 'stiffness', sub)
    damping = _get(spec, 'damping', float, sub) if 'damping' in spec else 0.0
    if damping < 0.0:
        raise SceneError(f'{sub}: field "damping" must be >= 0')
    return GraspObject(name=name, shape=shape, size=tuple(float(v) for v in size),
                       mass=_positive(spec, 'mass', sub),
                       friction=_positive(spec, 'friction', sub), stiffness=stiffness,
                       damping=damping, source=_get(spec, 'source', str, sub))


GRASP_FIELDS = {'gravity': 3, 'hand_pose': 16, 'others_kp': 0, 'others_kd': 0, 'tip_radius': 0,
                'skin_stiffness': 0, 'skin_damping': 0, 'goal_at': 0, 'hand_over': 0}


def _grasp(raw: dict, where: str) -> dict[str, Any]:
    grasp, sub = _get(raw, 'grasp', dict, where), f'{where}: grasp'
    for key, length in GRASP_FIELDS.items():
        if length:
            value = _get(grasp, key, list, sub)
            if len(value) != length or not all(isinstance(v, (int, float)) for v in value):
                raise SceneError(f'{sub}: field "grasp.{key}" must be {length} numbers')
        elif key == 'hand_over':
            if _get(grasp, key, float, sub) < 0.0:
                raise SceneError(f'{sub}: field "grasp.hand_over" must be >= 0 s')
        else:
            _positive(grasp, key, sub)
    fingers = _get(grasp, 'fingers', dict, sub)
    if 'thumb' not in fingers or len(fingers) < 2 or not set(fingers) <= set(FINGERS):
        raise SceneError(f'{sub}: field "grasp.fingers" must name the thumb and one to three '
                         f'of {[f for f in FINGERS if f != "thumb"]}, got {sorted(fingers)}')
    for finger, poses in fingers.items():
        for key in ('pose', 'contact_pose'):
            value = _get(poses or {}, key, list, f'{sub}.fingers.{finger}')
            if len(value) != 4 or not all(isinstance(v, (int, float)) for v in value):
                raise SceneError(f'{sub}: field "grasp.fingers.{finger}.{key}" must be 4 '
                                 'numbers (rad)')
    disturbances = grasp.get('disturbances') or {}
    for name, spec in disturbances.items():
        if name not in DISTURBANCES or not isinstance(spec, dict):
            raise SceneError(f'{sub}: field "grasp.disturbances.{name}": known disturbances '
                             f'are {sorted(DISTURBANCES)}, each a mapping')
        for key, length in DISTURBANCES[name].items():
            value = spec.get(key)
            ok = (isinstance(value, list) and len(value) == length
                  and all(isinstance(v, (int, float)) for v in value)) if length else \
                (isinstance(value, (int, float)) and not isinstance(value, bool) and value >= 0)
            if not ok:
                raise SceneError(f'{sub}: field "grasp.disturbances.{name}.{key}" must be '
                                 f'{f"{length} numbers" if length else "a number >= 0"}')
    # The thumb first: it opposes the others (its tip is the scene's `array`).
    ordered = {'thumb': fingers['thumb'], **{f: fingers[f] for f in FINGERS
                                             if f in fingers and f != 'thumb'}}
    return {**grasp, 'fingers': ordered, 'disturbances': dict(disturbances)}


# Opt-in disturbances of a grasp scene (sim/grasp.py): field -> numbers it takes (0: one).
DISTURBANCES = {'push': {'at': 0, 'duration': 0, 'force': 3},    # s, s, N in the base frame
                'added_mass': {'at': 0, 'mass': 0}}               # s, kg


def _press_tour(raw: dict, where: str) -> tuple[str, ...]:
    if 'press_tour' not in raw:
        return ()
    tour = raw['press_tour']
    if not isinstance(tour, list) or not tour or not all(isinstance(a, str) for a in tour):
        raise SceneError(f'{where}: field "press_tour" must be a list of array names')
    return tuple(tour)


def session_seed(base: int, array: str, plate: str, session: int) -> int:
    """A distinct, reproducible seed per (array, plate, session)."""
    entropy = [base, zlib.crc32(array.encode()), zlib.crc32(plate.encode()), session]
    return int(np.random.SeedSequence(entropy).generate_state(1)[0])
