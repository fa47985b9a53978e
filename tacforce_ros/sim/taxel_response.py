"""Base uSkin taxel response: per-taxel force in its frame -> raw 16-bit counts.

Counts = baseline + span * tanh(slope * coupled_load / span), clamped to 0..65535. The load is
(shear x, shear y, compression): the elastomer transmits shear and pushes the magnet towards the
Hall chip, but never pulls it away, so tension reads as zero compression. Per-taxel variation and
cross-axis coupling are the `taxel_variation` effect; this is the minimum that produces counts.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Rest values: X/Y near mid-scale, Z about 33,600-37,600 (docs/PROTOCOLS.md section 1, XELA
# replayer ranges); Z rises up to ~+10,085 counts above baseline and XELA warns against more
# than 3 N normal per cell, so the Z span is ~10,000 counts reached near 3 N. Shear sensitivity
# about half the normal one (Tomo et al. 2018, uSkin); slopes are our estimates.
# The Hall chip reads zero field at mid-scale (MLX90393 unsigned output at RES_XYZ 2,
# datasheet Table 21): X/Y rest there, Z above it with the magnet's field.
CHIP_ZERO = 32768.0
BASELINE = (CHIP_ZERO, CHIP_ZERO, 35000.0)
SLOPE = (2500.0, 2500.0, 5000.0)      # counts/N at small load
SPAN = (6000.0, 6000.0, 10500.0)      # counts at saturation
COUNT_MAX = 65535.0


@dataclass
class ResponseParams:
    """Per-taxel parameters over the whole hand (368 taxels)."""
    baseline: np.ndarray        # (N, 3) counts
    slope: np.ndarray           # (N, 3) counts/N
    span: np.ndarray            # (N, 3) counts
    coupling: np.ndarray | None = None   # (N, 3, 3) load mixing, None = identity

    @classmethod
    def nominal(cls, n_taxels: int) -> ResponseParams:
        ones = np.ones((n_taxels, 1))
        return cls(baseline=ones * BASELINE, slope=ones * SLOPE, span=ones * SPAN)


def taxel_loads(local_force: np.ndarray) -> np.ndarray:
    """(n, 3) force in each taxel frame (z out of the skin) -> (shear x, shear y, compression).

    `local_force` is the force the skin applies to the indenter, so pressing is +z."""
    loads = np.array(local_force, dtype=np.float64, copy=True)
    np.maximum(loads[:, 2], 0.0, out=loads[:, 2])
    return loads


def counts_from_loads(loads: np.ndarray, params: ResponseParams, rows: np.ndarray | slice
                      ) -> np.ndarray:
    """(n, 3) loads of the taxels `rows` (indices into the hand) -> float counts, unclamped."""
    if params.coupling is not None:
        loads = np.einsum('nij,nj->ni', params.coupling[rows], loads)
    span = params.span[rows]
    return params.baseline[rows] + span * np.tanh(params.slope[rows] * loads / span)


def to_uint16(counts: np.ndarray) -> np.ndarray:
    """Clamp float counts to the 16-bit range and round."""
    return np.rint(np.clip(counts, 0.0, COUNT_MAX)).astype(np.uint16)
