"""Taxels whose readings cannot be trusted, found frame by frame so that the array they belong to
is flagged instead of publishing a confident wrong force.

* clipped: a channel at the end of XELA's 16-bit range (0 or 65535): the reading says only that
  the true value is beyond it.
* frozen: all three channels unchanged for `frozen_frames` frames in a row (a stuck or dead
  taxel, or a readout that stopped updating). A live taxel is never that still: at rest its
  readings move by about 1.0 / 0.9 / 3.1 counts rms on X / Y / Z (medians over the 32 taxels of
  the 150 public uSkin 4x4 recordings of imanlab/tactile_prediction_flat_dataset), so the chance
  that all three keep their integer value from one frame to the next is below 1 %, and for
  `frozen_frames` = 25 (0.25 s at 100 Hz) below 1e-48. A quiet taxel is told from a frozen one
  by that noise.
* out of range: a channel standardised by the array's model (z = (x - tare - mean) / std, the
  input the model sees) beyond `out_of_range` in magnitude: far outside what the array was
  calibrated on, where no model's answer can be trusted (the runtime's OOD score is the largest
  |z| of the array, published with every estimate). Coarse on purpose: a channel's spread in
  training is not its range, and normal presses reach |z| of 25-48, so only a reading thousands
  of counts beyond them is flagged.

Pure numpy, and cheap while every taxel is healthy: three comparisons of the frame per tick.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

COUNT_MAX = 65535               # XELA uSkin readings are 16-bit
FROZEN_FRAMES = 25              # 0.25 s at 100 Hz (see the module docstring)
# |z| beyond which a channel is far outside its calibration. In normal pressing the pressed
# array's largest |z| reaches 25-48 (paper sequence, spherical plate, each fingertip, shipped
# M3-lambda models, seed 0; 1.6 on the untouched arrays): twice that is "far". On a channel
# of the calibration's median spread (60-100 counts) that is 6,000-10,000 counts.
OUT_OF_RANGE = 100.0

CLIPPED, FROZEN, OUT_OF_RANGE_KIND = 'clipped', 'frozen', 'out of range'
TAXEL_STATUS = 'taxel '      # how every fault's status starts (fault_status)


@dataclass(frozen=True)
class TaxelFault:
    taxel: int          # index in the frame the checker was given
    kind: str           # CLIPPED, FROZEN or OUT_OF_RANGE_KIND
    detail: str = ''    # e.g. which end of the range a clipped channel is at


class TaxelHealth:
    """Per-frame check of (n, 3) raw counts; stateful (it remembers the last frame and how long
    each taxel has been unchanged), so give it every frame, in order."""

    def __init__(self, n_taxels: int, frozen_frames: int | None = FROZEN_FRAMES) -> None:
        """`frozen_frames` None: frozen taxels are not looked for."""
        if frozen_frames is not None and frozen_frames < 2:
            raise ValueError(f'frozen_frames must be at least 2, not {frozen_frames}')
        self.n_taxels = n_taxels
        self.frozen_frames = frozen_frames
        self._last = np.full((n_taxels, 3), -1.0)       # no reading equals it
        self._still = np.zeros(n_taxels, dtype=np.int64)
        self._same = np.empty((n_taxels, 3), dtype=bool)
        self._unchanged = np.empty(n_taxels, dtype=bool)

    def check(self, counts: np.ndarray) -> list[TaxelFault]:
        """The faulty taxels of this frame, clipped before frozen; [] when all are healthy."""
        counts = np.asarray(counts)
        if counts.shape != (self.n_taxels, 3):
            raise ValueError(f'counts of shape {counts.shape}, expected ({self.n_taxels}, 3)')
        # The healthy tick in a few whole-frame calls; the per-taxel work only on a fault.
        in_range = counts.min() > 0 and counts.max() < COUNT_MAX
        still = False
        if self.frozen_frames is not None:
            np.equal(counts, self._last, out=self._same)
            self._same.all(axis=1, out=self._unchanged)
            self._still += 1
            self._still *= self._unchanged          # back to 0 where any channel moved
            np.copyto(self._last, counts)
            still = self._still.max() >= self.frozen_frames - 1
        if in_range and not still:
            return []
        low, high = (counts <= 0).any(axis=1), (counts >= COUNT_MAX).any(axis=1)
        frozen = (self._still >= self.frozen_frames - 1) if still else np.zeros_like(low)
        return ([TaxelFault(int(k), CLIPPED, 'reads 0') for k in np.flatnonzero(low)]
                + [TaxelFault(int(k), CLIPPED, f'reads {COUNT_MAX}')
                   for k in np.flatnonzero(high & ~low)]
                + [TaxelFault(int(k), FROZEN) for k in np.flatnonzero(frozen & ~low & ~high)])


def fault_status(fault: TaxelFault, taxel_in_array: int) -> str:
    """The status an array's estimate carries for its fault: names the taxel (its index within
    the array, as the hand description and the message list it)."""
    detail = f' ({fault.detail})' if fault.detail else ''
    return f'{TAXEL_STATUS}{taxel_in_array} {fault.kind}{detail}'
