"""Reference readings of the magnetic skin, kept to show that making it faster left what it
computes as it was.

`python test/sim/skin_reference.py OUT.npz` writes them: the pressed array's counts (uint16) in
calibration sessions of a curved and a flat array on every plate, and in the closed-loop scene
with the finger pressed by a constant torque; without the effects that act on the chip's counts
(noise, temperature drift, crosstalk: not what this checks). The file beside this
one, data/magnetic_skin_reference.npz, was written by the code of 9d82c4b, before the speed-up
(run from a checkout of it: `PYTHONPATH=<checkout> python test/sim/skin_reference.py ...`);
test_sim_skin_physics.py compares today's readings with it.
"""
from __future__ import annotations

import dataclasses
import sys
import warnings
from pathlib import Path

import numpy as np
import yaml

ARRAYS = ('index_tip', 'index_middle')          # curved fingertip, flat phalanx
PLATES = ('button', 'flat', 'fillet', 'convex', 'edge', 'spherical')
CALIBRATION_SECONDS = 6.0
CLOSED_LOOP_SECONDS = 3.0
EVERY = 10                                      # frames kept: every 10th tactile frame
SEED = 0
REFERENCE = Path(__file__).parent / 'data' / 'magnetic_skin_reference.npz'


CHIP_EFFECTS = ('taxel_noise', 'temperature_drift', 'crosstalk')
# The reference predates magnets and modules that differ (drawn after the rest readings): with
# no spread the skin computes what it computed then.
ALIKE = {'remanence_spread': 0.0, 'module_layer_spread': 0.0, 'module_modulus_spread': 0.0}


def magnetic_scene(folder: Path, name: str):
    """The shipped scene `name` on the magnetic skin, without CHIP_EFFECTS."""
    from tacforce_ros.sim import load_scene
    from tacforce_ros.sim.effects.magnetic_skin import magnetic_skin_overlay
    path = folder / f'{name}_magnetic.yaml'
    path.write_text(yaml.safe_dump({'extends': name, 'effects': magnetic_skin_overlay(**ALIKE)},
                                   sort_keys=False))
    scene = load_scene(str(path))
    return dataclasses.replace(scene, effects={name: params for name, params in
                                               scene.effects.items()
                                               if name not in CHIP_EFFECTS})


def _frames(sim, rows, seconds: float, torque=None) -> np.ndarray:
    kept = []
    for _ in range(int(round(seconds / sim.dt))):
        sample = sim.step() if torque is None else sim.step(torque)
        if sample.delivered['tactile'] and sample.tactile_fresh:
            kept.append(np.array(sample.taxel_counts[rows]))
    return np.stack(kept[::EVERY])


def readings(folder: Path) -> dict[str, np.ndarray]:
    """{case: (frames, taxels, 3) uint16} of every case above, scene files written to
    `folder`."""
    from tacforce_ros.hand.description import load_hand
    from tacforce_ros.sim import make_simulator
    from tacforce_ros.sim.scene import calibration_scene_name
    hand = load_hand(None)
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        for array in ARRAYS:
            rows = hand.array(array).flat_indices
            for plate in PLATES:
                sim = make_simulator(
                    magnetic_scene(folder, calibration_scene_name(array, plate)), hand, seed=SEED)
                out[f'{array}.{plate}'] = _frames(sim, rows, CALIBRATION_SECONDS)
        sim = make_simulator(magnetic_scene(folder, 'closed_loop_spherical'), hand, seed=SEED)
        torque = np.zeros(16)
        torque[sim.joints] = (0.0, 0.05, 0.05, 0.03)     # the finger pressed on the plate
        out['closed_loop.spherical'] = _frames(sim, hand.array('index_tip').flat_indices,
                                               CLOSED_LOOP_SECONDS, torque)
    return out


if __name__ == '__main__':
    import tempfile
    with tempfile.TemporaryDirectory() as tmp:
        cases = readings(Path(tmp))
    np.savez_compressed(sys.argv[1], **cases)
    for case, counts in cases.items():
        moved = np.abs(counts.astype(np.int64) - counts[:1]).max()
        print(f'{case}: {len(counts)} frames, up to {moved} counts from the first')
