"""The sensor chain shared by both simulators: contact -> uSkin counts, wrench -> RDT counts."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacforce_ros.hand.description import HandDescription, TaxelArray
from tacforce_ros.sim.contact import PressureModel
from tacforce_ros.sim.effects import Pipeline
from tacforce_ros.sim.sample import StepState
from tacforce_ros.sim.scene import Plate
from tacforce_ros.sim.taxel_response import (ResponseParams, counts_from_loads, taxel_loads,
                                             to_uint16)

# Temperature the readings settle at after the paper's 30 min warm-up (section IV-A): our
# estimate of a powered hand's skin temperature.
WARM_TEMPERATURE = 305.15   # K


@dataclass
class EffectContext:
    """What effects may look at when they reset (and, by reference, later)."""
    hand: HandDescription
    array: TaxelArray
    rows: np.ndarray              # (n,) the array's taxels in XELA flat order
    array_of_taxel: np.ndarray    # (368,) array index of each flat taxel
    n_taxels: int
    dt: float                     # s between tactile frames
    physics_dt: float             # s per simulator step (= dt in calibration scenes)
    params: ResponseParams
    idle_counts: np.ndarray | None = None   # (368, 3) float counts with no load


class TactileSensor:
    """Whole-hand uSkin readout with one array in contact with a plate."""

    def __init__(self, hand: HandDescription, array_name: str, plate: Plate,
                 pipeline: Pipeline, frame_dt: float, physics_dt: float | None = None) -> None:
        self.hand = hand
        self.array = hand.array(array_name)
        self.pipeline = pipeline
        self.plate = plate
        self.pressure = PressureModel(self.array.positions, plate)
        self.skin = pipeline.get('magnetic_skin')   # None: the empirical response
        self._rows = self.array.flat_rows
        array_of = np.empty(hand.n_taxels, np.int64)
        for index, array in enumerate(hand.arrays):
            array_of[array.flat_indices] = index
        self.ctx = EffectContext(hand=hand, array=self.array, rows=self.array.flat_indices,
                                 array_of_taxel=array_of, n_taxels=hand.n_taxels, dt=frame_dt,
                                 physics_dt=frame_dt if physics_dt is None else physics_dt,
                                 params=ResponseParams.nominal(hand.n_taxels))

    def reset(self, seed: int, sensor_seed: int) -> None:
        """Session draws from `seed`; the hand's physical parameters from `sensor_seed`."""
        ctx = self.ctx
        ctx.params = ResponseParams.nominal(ctx.n_taxels)
        self.pipeline.reset(seed, ctx, sensor_seed)
        self.pipeline.run('response', ctx)
        if self.skin is None:
            ctx.idle_counts = counts_from_loads(np.zeros((ctx.n_taxels, 3)), ctx.params,
                                                slice(None))
        # The array's rows of the response, gathered once: they are fixed from here on.
        rows, p = ctx.rows, ctx.params
        self._array_params = ResponseParams(
            baseline=p.baseline[rows], slope=p.slope[rows], span=p.span[rows],
            coupling=None if p.coupling is None else p.coupling[rows])
        self._warm = np.full(ctx.n_taxels, WARM_TEMPERATURE)

    def measure(self, state: StepState) -> None:
        """Fill state.counts / temperatures / counts_out from state.contact."""
        contact, run = state.contact, self.pipeline.run
        if self.skin is not None:
            counts = self.ctx.idle_counts.copy()
            counts[self._rows] = self.skin.counts(contact, self.plate)
            self._finish(state, counts)
            return
        weights = self.pressure.weights(contact)
        state.depth = self.pressure.depth
        state.taxel_force = weights[:, None] * contact.force
        run('taxel_force', state)
        # Force on each taxel, expressed in its own frame: R_i^T f_i.
        state.local_force = np.einsum('nji,nj->ni', self.array.rotations, state.taxel_force)
        run('local_force', state)
        counts = self.ctx.idle_counts.copy()
        counts[self._rows] = counts_from_loads(taxel_loads(state.local_force),
                                               self._array_params, slice(None))
        self._finish(state, counts)

    def _finish(self, state: StepState, counts: np.ndarray) -> None:
        state.counts = counts
        state.temperatures = self._warm
        self.pipeline.run('counts', state)
        state.counts_out = to_uint16(state.counts)
        self.pipeline.run('readout', state)
