"""The hand as data: taxel arrays, their layouts and frames, and XELA's flat taxel order.

Loaded from ``config/hand/<hand>.yaml``. Taxel positions and taxel frames R_i^0 are generated
here from each module type's regular geometry (grid, pitch, curvature), so the YAML stays short.
No ROS import: this runs in offline training as well as in the 100 Hz nodes.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import yaml

from tacforce_ros.paths import config_dir
from tacforce_ros.rig import FINGERS

KINDS = ('fingertip', 'phalanx', 'palm')
ARRAY_KIND_TITLES = {'fingertip': 'curved fingertips', 'phalanx': 'flat phalanx pads',
                     'palm': 'palm pads'}
SIDES = ('right', 'left')
DEFAULT_SIDE = 'right'     # the first hand described: a file that names no hand is of it
# A prefix to the frame ids (robot_state_publisher's frame_prefix), and what it may be.
FRAME_PREFIX_PATTERN = (r'(?!/)[A-Za-z0-9_/]*', 'a frame-id prefix: letters, digits, _ and /, '
                        'not starting with / (tf2 frame ids do not)')
_ORTHONORMAL_TOL = 1e-9


def hand_config(side: str = DEFAULT_SIDE) -> Path:
    """The shipped description of the `side` hand."""
    return config_dir() / 'hand' / f'allegro_{side}_uskin.yaml'


def side_of(value: object) -> str:
    """The hand side a bag, dataset or model file names (empty or None: DEFAULT_SIDE)."""
    side = str(value or DEFAULT_SIDE)
    if side not in SIDES:
        raise ValueError(f'hand side {side!r} is not one of {list(SIDES)}')
    return side


class HandConfigError(ValueError):
    """A hand configuration that cannot be used; the message names the offending field."""


@dataclass(frozen=True, eq=False)
class TaxelArray:
    """One uSkin module: its taxels' layout and where each taxel sits in XELA's flat order."""

    name: str
    module_code: str
    kind: str
    finger: str | None
    parent_link: str
    frame_id: str
    n_taxels: int
    grid_index: np.ndarray     # (h, w) int64, taxel index per grid cell, -1 where no taxel
    positions: np.ndarray      # (n, 3) float64 [m], taxel centres in {S0}
    rotations: np.ndarray      # (n, 3, 3) float64, R_i^0: taxel frame {S_i} -> {S0}
    flat_indices: np.ndarray   # (n,) int64, index of each taxel in the flat 368-taxel order
    neighbours: tuple[str, ...]
    hand_side: str             # 'right' | 'left': the right hand's index_tip is not the left's

    @property
    def flat_rows(self) -> slice | np.ndarray:
        """flat_indices as a slice where they are contiguous (numpy then indexes with views,
        not copies: the simulator's step path), else the indices."""
        first = int(self.flat_indices[0])
        if np.array_equal(self.flat_indices, np.arange(first, first + self.n_taxels)):
            return slice(first, first + self.n_taxels)
        return self.flat_indices


@dataclass(frozen=True, eq=False)
class HandDescription:
    """All arrays of one hand, in config order, plus the URDF and frames they refer to."""

    side: str
    arrays: tuple[TaxelArray, ...]
    urdf_path: Path
    base_frame: str
    ft_frame: str
    sensor_model: str = ''     # XELA model string the server reports for this hand
    # The F/T frame of the rig as mounted for a finger whose pad does not face ft_frame (the
    # closed loop of that finger pushes a plate there); other fingers use ft_frame.
    rig_frames: Mapping[str, str] = field(default_factory=dict)
    _by_name: dict[str, int] = field(init=False, repr=False)
    _gather: np.ndarray = field(init=False, repr=False)   # flat positions in array-major order
    _scatter: np.ndarray = field(init=False, repr=False)  # inverse permutation of _gather
    _bounds: np.ndarray = field(init=False, repr=False)   # split points along the taxel axis

    def __post_init__(self) -> None:
        gather = np.concatenate([a.flat_indices for a in self.arrays])
        scatter = np.empty_like(gather)
        scatter[gather] = np.arange(gather.size)
        sizes = np.array([a.n_taxels for a in self.arrays], dtype=np.int64)
        for name, value in (('_by_name', {a.name: i for i, a in enumerate(self.arrays)}),
                            ('_gather', _read_only(gather)), ('_scatter', _read_only(scatter)),
                            ('_bounds', np.cumsum(sizes)[:-1])):
            object.__setattr__(self, name, value)

    def rig_frame(self, finger: str) -> str:
        """The F/T frame of the rig mounted for `finger`'s fingertip."""
        return self.rig_frames.get(finger, self.ft_frame)

    @property
    def n_taxels(self) -> int:
        return int(self._gather.size)

    def array(self, name: str) -> TaxelArray:
        return self.arrays[self.index(name)]

    def index(self, name: str) -> int:
        try:
            return self._by_name[name]
        except KeyError:
            raise KeyError(f'no taxel array named {name!r}; known: {sorted(self._by_name)}') \
                from None

    def split(self, flat: np.ndarray) -> list[np.ndarray]:
        """(..., 368, k) in XELA's flat order -> one (..., n_i, k) block per array, config order."""
        flat = np.asarray(flat)
        if flat.ndim < 2 or flat.shape[-2] != self.n_taxels:
            raise ValueError(f'expected shape (..., {self.n_taxels}, k), got {flat.shape}')
        return np.split(np.take(flat, self._gather, axis=-2), self._bounds, axis=-2)

    def merge(self, per_array: Sequence[np.ndarray]) -> np.ndarray:
        """Inverse of split: per-array blocks (..., n_i, k) -> (..., 368, k) in the flat order."""
        if len(per_array) != len(self.arrays):
            raise ValueError(f'expected {len(self.arrays)} arrays, got {len(per_array)}')
        for block, arr in zip(per_array, self.arrays):
            if np.ndim(block) < 2 or np.shape(block)[-2] != arr.n_taxels:
                raise ValueError(f'{arr.name}: expected (..., {arr.n_taxels}, k), '
                                 f'got {np.shape(block)}')
        return np.take(np.concatenate(per_array, axis=-2), self._scatter, axis=-2)


def load_hand(path: str | Path | None = None) -> HandDescription:
    """Read and validate a hand YAML (default: config/hand/allegro_right_uskin.yaml)."""
    path = Path(path) if path is not None else hand_config()
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise HandConfigError(f'{path}: not valid YAML: {exc}') from exc
    if not isinstance(doc, dict):
        raise HandConfigError(f'{path}: top level must be a mapping')
    try:
        return _build(doc, path)
    except HandConfigError as exc:
        raise HandConfigError(f'{path}: {exc}') from None


# ---------------------------------------------------------------------------------- building

def _build(doc: dict, path: Path) -> HandDescription:
    modules = _require(doc, 'modules', dict, 'modules')
    raw_arrays = _require(doc, 'arrays', list, 'arrays')
    layouts = {name: _module_layout(spec, f'modules.{name}') for name, spec in modules.items()}
    side = _require(doc, 'side', str, 'side')
    if side not in SIDES:
        raise HandConfigError(f'side: {side!r} is not one of {list(SIDES)}')
    arrays = tuple(_array(raw, layouts, f'arrays[{i}]', side)
                   for i, raw in enumerate(raw_arrays))
    _check_cross_array(arrays)
    config_root = path.resolve().parent.parent   # <config>/hand/<file>.yaml -> <config>
    urdf_rel = _require(doc, 'urdf', str, 'urdf')
    return HandDescription(
        side=side,
        arrays=arrays,
        urdf_path=(config_root / urdf_rel).resolve(),
        base_frame=_require(doc, 'base_frame', str, 'base_frame'),
        ft_frame=_require(doc, 'ft_frame', str, 'ft_frame'),
        sensor_model=str(doc.get('sensor_model', '')),
        rig_frames=_rig_frames(doc, {a.finger for a in arrays if a.finger}),
    )


def _rig_frames(doc: dict, fingers: set[str]) -> dict[str, str]:
    raw = doc.get('rig_frames') or {}
    if not isinstance(raw, dict) or not set(raw) <= fingers:
        raise HandConfigError(f'rig_frames: expected finger -> frame for fingers of '
                              f'{sorted(fingers)}, got {raw!r}')
    return {str(k): str(v) for k, v in raw.items()}



@dataclass(frozen=True)
class _Layout:
    kind: str
    grid_index: np.ndarray   # (h, w) 0-based taxel index, -1 where empty
    positions: np.ndarray
    rotations: np.ndarray


def _module_layout(spec: Any, where: str) -> _Layout:
    if not isinstance(spec, dict):
        raise HandConfigError(f'{where}: must be a mapping')
    kind = _require(spec, 'kind', str, f'{where}.kind')
    if kind not in KINDS:
        raise HandConfigError(f'{where}.kind: {kind!r} is not one of {KINDS}')
    pitch = _positive(spec, 'pitch', where)
    grid_numbers = _grid(spec.get('grid'), f'{where}.grid')
    grid_index = grid_numbers - 1                    # XELA numbers taxels from 1; 0 marks no taxel
    rows, cols = np.nonzero(grid_index >= 0)
    order = np.argsort(grid_index[rows, cols])       # taxel order = XELA taxel number
    rows, cols = rows[order], cols[order]
    h, w = grid_index.shape
    # Row 0 is the distal edge (+x), column 0 the +y edge; centred on the array origin.
    along = ((h - 1) / 2.0 - rows) * pitch
    across = ((w - 1) / 2.0 - cols) * pitch
    if 'rotations' in spec:   # irregular module: explicit geometry, in XELA taxel-number order
        positions = _explicit(spec, 'positions', (rows.size, 3), where)
        return _Layout(kind, grid_index, positions,
                       _explicit(spec, 'rotations', (rows.size, 3, 3), where))
    if 'radius' in spec:
        radius = _positive(spec, 'radius', where)
        row0_arc = float(spec.get('row0_arc', (h - 1) / 2.0 * pitch))
        positions, normals, tangents = _capsule_surface(row0_arc - rows * pitch, across, radius)
    else:
        n = rows.size
        positions = np.column_stack([along, across, np.zeros(n)])
        normals = np.tile([0.0, 0.0, 1.0], (n, 1))
        tangents = np.tile([1.0, 0.0, 0.0], (n, 1))
    return _Layout(kind, grid_index, positions, _frames(tangents, normals))


def _capsule_surface(arc: np.ndarray, across: np.ndarray, radius: float):
    """Taxels on a fingertip: a hemispherical cap (arc > 0) on a cylinder along x (arc <= 0).

    ``arc`` is the surface distance from the cap's equator towards the apex, ``across`` the
    surface distance around the finger from the palmar line. Origin: centre of the cap.
    Returns positions, outward unit normals and unit distal tangents, each (n, 3).
    """
    phi = across / radius                       # angle around the finger axis, from +z towards +y
    theta = np.clip(arc, 0.0, None) / radius    # latitude on the cap; 0 on the cylinder
    normals = np.column_stack([np.sin(theta), np.cos(theta) * np.sin(phi),
                               np.cos(theta) * np.cos(phi)])
    # On the cylinder the point moves back along -x by the (negative) arc length.
    positions = radius * normals + np.column_stack([np.clip(arc, None, 0.0),
                                                    np.zeros_like(arc), np.zeros_like(arc)])
    tangents = np.column_stack([np.cos(theta), -np.sin(theta) * np.sin(phi),
                                -np.sin(theta) * np.cos(phi)])
    return positions, normals, tangents


def _frames(tangents: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """R_i^0 with columns (x = tangent, y = z cross x, z = normal), one per taxel."""
    y = np.cross(normals, tangents)
    return np.stack([tangents, y, normals], axis=-1)


def _array(raw: Any, layouts: dict[str, _Layout], where: str, side: str) -> TaxelArray:
    if not isinstance(raw, dict):
        raise HandConfigError(f'{where}: must be a mapping')
    name = _require(raw, 'name', str, f'{where}.name')
    where = f'{where} ({name})'
    module = _require(raw, 'module', str, f'{where}.module')
    if module not in layouts:
        raise HandConfigError(f'{where}.module: unknown module type {module!r}; '
                              f'defined: {sorted(layouts)}')
    layout = layouts[module]
    finger = raw.get('finger', 'missing')
    if finger == 'missing':
        raise HandConfigError(f'{where}.finger: missing key (use null for the palm)')
    if (finger is None) != (layout.kind == 'palm') or (finger is not None
                                                      and finger not in FINGERS):
        raise HandConfigError(f'{where}.finger: {finger!r} does not fit a {layout.kind} array '
                              f'(fingers: {FINGERS}, palm: null)')
    n_taxels = _require(raw, 'n_taxels', int, f'{where}.n_taxels')
    n_grid = int(np.count_nonzero(layout.grid_index >= 0))
    if n_taxels != n_grid:
        raise HandConfigError(f'{where}.n_taxels: {n_taxels} but module {module} grid has '
                              f'{n_grid} taxels')
    flat = np.asarray(_require(raw, 'flat_indices', list, f'{where}.flat_indices'))
    if flat.shape != (n_taxels,) or not np.issubdtype(flat.dtype, np.integer):
        raise HandConfigError(f'{where}.flat_indices: need {n_taxels} integers, got {flat.size}')
    neighbours = _require(raw, 'neighbours', list, f'{where}.neighbours')
    _check_rotations(layout.rotations, f'{where}.rotations (module {module})')
    return TaxelArray(
        name=name,
        module_code=_require(raw, 'module_code', str, f'{where}.module_code'),
        kind=layout.kind,
        finger=finger,
        parent_link=_require(raw, 'parent_link', str, f'{where}.parent_link'),
        frame_id=_require(raw, 'frame_id', str, f'{where}.frame_id'),
        n_taxels=n_taxels,
        grid_index=_read_only(layout.grid_index.astype(np.int64)),
        positions=_read_only(layout.positions.astype(np.float64)),
        rotations=_read_only(layout.rotations.astype(np.float64)),
        flat_indices=_read_only(flat.astype(np.int64)),
        neighbours=tuple(str(n) for n in neighbours),
        hand_side=side,
    )


def _check_cross_array(arrays: tuple[TaxelArray, ...]) -> None:
    names = [a.name for a in arrays]
    for field_name in ('name', 'frame_id', 'module_code'):
        values = [getattr(a, field_name) for a in arrays]
        dupes = sorted({v for v in values if values.count(v) > 1})
        if dupes:
            raise HandConfigError(f'arrays[*].{field_name}: duplicates {dupes}')
    total = sum(a.n_taxels for a in arrays)
    owner: dict[int, str] = {}
    for a in arrays:
        for idx in a.flat_indices.tolist():
            if not 0 <= idx < total:
                raise HandConfigError(f'arrays ({a.name}).flat_indices: {idx} outside '
                                      f'0..{total - 1}')
            if idx in owner:
                raise HandConfigError(f'arrays ({a.name}).flat_indices: {idx} duplicates an index '
                                      f'of {owner[idx]}')
            owner[idx] = a.name
    by_name = {a.name: a for a in arrays}
    for a in arrays:
        for other in a.neighbours:
            if other not in by_name or other == a.name:
                raise HandConfigError(f'arrays ({a.name}).neighbours: unknown array {other!r} '
                                      f'(known: {names})')
            if a.name not in by_name[other].neighbours:
                raise HandConfigError(f'arrays ({a.name}).neighbours: {other!r} does not list '
                                      f'{a.name!r} back (adjacency must be mutual)')


def _check_rotations(rotations: np.ndarray, where: str) -> None:
    gram_error = np.abs(np.einsum('nji,njk->nik', rotations, rotations) - np.eye(3)).max()
    det = np.linalg.det(rotations)
    if gram_error > _ORTHONORMAL_TOL or np.abs(det - 1.0).max() > _ORTHONORMAL_TOL:
        raise HandConfigError(f'{where}: not proper rotations (|R^T R - I| = {gram_error:.2e}, '
                              f'det in [{det.min():.6f}, {det.max():.6f}])')


def _grid(raw: Any, where: str) -> np.ndarray:
    try:
        grid = np.asarray(raw, dtype=np.int64)
    except (TypeError, ValueError):
        raise HandConfigError(f'{where}: must be a rectangular list of integer rows') from None
    if grid.ndim != 2 or grid.size == 0:
        raise HandConfigError(f'{where}: must be a non-empty rectangular list of rows')
    numbers = np.sort(grid[grid > 0])
    if grid.min() < 0 or not np.array_equal(numbers, np.arange(1, numbers.size + 1)):
        raise HandConfigError(f'{where}: cells must hold taxel numbers 1..n, each once (0 = empty)')
    return grid


def _require(mapping: dict, key: str, kind: type, where: str) -> Any:
    if key not in mapping:
        raise HandConfigError(f'{where}: missing key')
    value = mapping[key]
    # bool is an int subclass; a YAML `true` is never a valid count or index.
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        raise HandConfigError(f'{where}: expected {kind.__name__}, got {type(value).__name__} '
                              f'{value!r}')
    return value


def _explicit(spec: dict, key: str, shape: tuple[int, ...], where: str) -> np.ndarray:
    try:
        value = np.asarray(spec.get(key), dtype=np.float64)
    except (TypeError, ValueError):
        value = np.empty(0)
    if value.shape != shape or not np.isfinite(value).all():
        raise HandConfigError(f'{where}.{key}: need finite numbers of shape {shape}, '
                              f'got shape {value.shape}')
    return value


def _positive(spec: dict, key: str, where: str) -> float:
    value = spec.get(key)
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not value > 0:
        raise HandConfigError(f'{where}.{key}: must be a positive number [m], got {value!r}')
    return float(value)


def _read_only(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a
