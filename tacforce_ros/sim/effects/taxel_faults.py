"""Faulty taxels, as worn or damaged skins have them; opt-in, per scene, each named by its array
and its taxel index within the array:

* stuck: the taxel keeps the reading it had when the fault began (a readout that stopped
  updating it): frozen, noise and all;
* dead: it reads a constant from then on, 0 on every channel unless `value` says otherwise;
* clipped: one channel (`axis`) reads the end of the 16-bit range (`rail`: high 65535, low 0)
  from then on, as a saturated channel does.

    effects:
      taxel_faults:
        faults:
          - {array: index_tip, taxel: 7, kind: stuck, at: 2.0}
          - {array: index_tip, taxel: 12, kind: dead}
          - {array: index_middle, taxel: 3, kind: clipped, axis: z, rail: high}

`at` is the simulated second the fault begins (0: from the start). The kinds are how such faults
show in a stream of readings; which of them a given skin develops, and how often, no public
source says: the scenes that use them are fault drills, not estimates of a rate.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tacforce_ros.sim.effects import Effect

KINDS = ('stuck', 'dead', 'clipped')
AXES = {'x': 0, 'y': 1, 'z': 2}
RAILS = {'high': 65535, 'low': 0}


@dataclass
class TaxelFaults(Effect):
    name = 'taxel_faults'
    faults: list = field(default_factory=list)

    def __post_init__(self) -> None:
        allowed = {'array', 'taxel', 'kind', 'at', 'axis', 'rail', 'value'}
        for k, fault in enumerate(self.faults):
            where = f'faults[{k}]'
            if not isinstance(fault, dict):
                raise ValueError(f'{where}: a mapping with array, taxel and kind')
            unknown = sorted(set(fault) - allowed)
            if unknown:
                raise ValueError(f'{where}: unknown keys {unknown} (known: {sorted(allowed)})')
            missing = [key for key in ('array', 'taxel', 'kind') if key not in fault]
            if missing:
                raise ValueError(f'{where}: missing {missing}')
            if fault['kind'] not in KINDS:
                raise ValueError(f'{where}.kind: {fault["kind"]!r} is not one of {list(KINDS)}')
            if not isinstance(fault['taxel'], int) or fault['taxel'] < 0:
                raise ValueError(f'{where}.taxel: {fault["taxel"]!r} is not a taxel index')
            if fault.get('axis', 'z') not in AXES:
                raise ValueError(f'{where}.axis: {fault.get("axis")!r} is not one of x, y, z')
            if fault.get('rail', 'high') not in RAILS:
                raise ValueError(f'{where}.rail: {fault.get("rail")!r} is not high or low')
            value = fault.get('value', 0)
            if not isinstance(value, int) or not 0 <= value <= 65535:
                raise ValueError(f'{where}.value: {value!r} is not a 16-bit reading')
            if float(fault.get('at', 0.0)) < 0.0:
                raise ValueError(f'{where}.at: {fault["at"]!r} must be >= 0 s')

    def reset(self, rng: np.random.Generator, ctx) -> None:
        self._active = []
        for k, fault in enumerate(self.faults):
            try:
                array = ctx.hand.array(fault['array'])
            except KeyError as exc:
                raise ValueError(f'taxel_faults.faults[{k}].array: {exc}') from None
            if fault['taxel'] >= array.n_taxels:
                raise ValueError(f'taxel_faults.faults[{k}].taxel: {fault["taxel"]} but '
                                 f'{array.name} has {array.n_taxels} taxels')
            self._active.append({'row': int(array.flat_indices[fault['taxel']]),
                                 'kind': fault['kind'], 'at': float(fault.get('at', 0.0)),
                                 'axis': AXES[fault.get('axis', 'z')],
                                 'rail': RAILS[fault.get('rail', 'high')],
                                 'value': int(fault.get('value', 0)), 'held': None})

    def on_readout(self, state) -> None:
        counts = state.counts_out
        for fault in self._active:
            if state.t < fault['at']:
                continue
            row = fault['row']
            if fault['kind'] == 'stuck':
                if fault['held'] is None:
                    fault['held'] = counts[row].copy()
                counts[row] = fault['held']
            elif fault['kind'] == 'dead':
                counts[row] = fault['value']
            else:
                counts[row, fault['axis']] = fault['rail']


EFFECT = TaxelFaults
