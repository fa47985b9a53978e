"""Effects: small, independently switchable pieces of realism, run as one pipeline.

Each effect is a dataclass of its parameters (defaults are the plausible magnitudes, with their
source) and defines hooks named `on_<stage>` that mutate the step state in place. The pipeline
collects, once at load, the hooks each stage needs; a stage with no enabled effect is an empty
tuple, so an effect that a scene does not name costs nothing on the step path.

Stages, in the order a step runs them:
  model        closed loop only, once at build: edits the simulated hand/world (MjSpec)
  response     once at reset: per-taxel response parameters
  taxel_force  each taxel's share of the contact force, in {S0}
  local_force  per-taxel force in its own frame
  counts       whole-hand float counts and temperatures (368 taxels)
  readout      the 16-bit counts the skin's electronics send (faulty taxels)
  wrench       the F/T wrench in {F}
  torque       closed loop: joint torques between command and the simulated actuators
  delivery     what each stream delivers (latency, drop-outs)
"""
from __future__ import annotations

import zlib
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

HAND_STREAM = 1   # tag of the hand's random streams (see Pipeline.reset)
STAGES = ('model', 'response', 'taxel_force', 'local_force', 'counts', 'readout', 'wrench',
          'torque', 'delivery')


@dataclass
class Effect:
    """Base of all effects. Subclasses set `name` and define some `on_<stage>(state)` hooks."""
    name: ClassVar[str] = ''
    supersedes: ClassVar[tuple[str, ...]] = ()   # effects whose part this one models itself

    def draw_hand(self, rng: np.random.Generator, ctx: Any) -> None:
        """Draw the parameters of the physical hand and its sensors (taxel gains, baselines,
        actuator constants, link tolerances): fixed per sensor seed, the same in every session."""

    def reset(self, rng: np.random.Generator, ctx: Any) -> None:
        """Draw what differs between sessions (noise, drift, state) and size buffers; ctx is the
        simulator's EffectContext."""


class Pipeline:
    """The enabled effects of a scene, with their hooks grouped per stage."""

    def __init__(self, effects: list[Effect]) -> None:
        self.effects = list(effects)
        for effect in self.effects:
            unknown = sorted(name for name in dir(effect) if name.startswith('on_')
                             and name[3:] not in STAGES)
            if unknown:     # a misspelt hook would otherwise never run, silently
                raise TypeError(f'effect {effect.name!r}: hooks {unknown} name no stage; '
                                f'stages are {list(STAGES)}')
        names = {e.name for e in self.effects}
        for effect in self.effects:
            both = sorted(names.intersection(effect.supersedes))
            if both:    # the same physics would be counted twice
                raise ValueError(f'effect {effect.name!r} models what {both} stand in for; '
                                 f'remove them from the scene (e.g. `{both[0]}: null`)')
        self.hooks: dict[str, tuple] = {
            stage: tuple(getattr(e, f'on_{stage}') for e in self.effects
                         if hasattr(e, f'on_{stage}'))
            for stage in STAGES}

    @classmethod
    def from_scene(cls, effects: dict[str, dict[str, Any]]) -> Pipeline:
        return cls([EFFECTS[name](**params) for name, params in effects.items()])

    def reset(self, seed: int, ctx: Any, sensor_seed: int) -> None:
        """The hand's physical parameters from `sensor_seed`, the session's draws from `seed`."""
        # One independent stream per effect (keyed by its name), so switching one effect on
        # does not change the random draws of any other; the hand's streams carry a tag so they
        # never coincide with a session's, even when both seeds are equal.
        # A left hand is another hand than the right of the same sensor_seed (a lab's two hands
        # have their own modules), so its streams carry its side; the right's are as they were.
        side = getattr(getattr(ctx, 'hand', None), 'side', 'right')
        tag = [HAND_STREAM] if side == 'right' else [HAND_STREAM, zlib.crc32(side.encode())]
        for effect in self.effects:
            key = zlib.crc32(effect.name.encode())
            effect.draw_hand(np.random.default_rng([sensor_seed, key, *tag]), ctx)
            effect.reset(np.random.default_rng([seed, key]), ctx)

    def run(self, stage: str, state: Any) -> None:
        for hook in self.hooks[stage]:
            hook(state)

    def get(self, name: str) -> Effect | None:
        return next((e for e in self.effects if e.name == name), None)

    def __contains__(self, name: str) -> bool:
        return self.get(name) is not None


def _registry() -> dict[str, type[Effect]]:
    from tacforce_ros.sim.effects import (actuator_limits, contact_offset, crosstalk,
                                          deformation, ft_noise, hysteresis, joint_friction,
                                          kinematic_mismatch, magnetic_skin, taxel_faults,
                                          taxel_noise, taxel_variation, temperature_drift,
                                          torque_gain_error, transport)
    modules = (taxel_variation, deformation, hysteresis, magnetic_skin, taxel_noise,
               temperature_drift, crosstalk, taxel_faults, ft_noise, actuator_limits,
               torque_gain_error, joint_friction, kinematic_mismatch, contact_offset, transport)
    return {m.EFFECT.name: m.EFFECT for m in modules}


EFFECTS: dict[str, type[Effect]] = _registry()
