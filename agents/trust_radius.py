"""The trust region's size adapted from realised against predicted improvement (``trust_adapt=True``).

Trust-region methods grow the region when the model's promise is kept and shrink it when it
is not (Nocedal & Wright, *Numerical Optimization*, Algorithm 4.1). In TLPS the promise of an
update is the mean gain in smoothed robustness ρ̂ of the batch's updated trajectories (or
repaired episodes) over the sampled ones; what it realises is how much the next batch's mean
ρ̂, sampled from the refit policy, gains over this batch's. With the ratio r of the two:

* r < 0.25: the next region is half as large (ε and ``action_epsilon`` are squared norms);
* r > 0.75: twice as large;
* otherwise, or when the promise was not positive: unchanged.

The factor stays within ``[1/64, 8]`` of the configured size. Research record: docs/tlps.md, H21.

Example:
    >>> radius = AdaptiveRadius()
    >>> radius.record(smooth_before=-10.0, smooth_after=-6.0)   # promised +4
    >>> radius.adapt(smooth_before=-9.5)                         # realised +0.5: r = 0.125
    0.5
    >>> radius.record(smooth_before=-9.5, smooth_after=-8.5)    # promised +1
    >>> radius.adapt(smooth_before=-8.4)                         # realised +1.1: r = 1.1
    1.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SHRINK_BELOW, GROW_ABOVE = 0.25, 0.75
SMALLEST, LARGEST = 1.0 / 64.0, 8.0


@dataclass
class AdaptiveRadius:
    """The factor on the configured trust-region size, and what the last update promised."""

    scale: float = 1.0
    previous: float = math.nan  # mean ρ̂ of the last batch, before its update
    predicted: float = math.nan  # the gain in mean ρ̂ that update promised

    def adapt(self, smooth_before: float) -> float:
        """Adapt the factor to a new batch's mean ρ̂ (sampled from the refit policy); return it."""
        if math.isfinite(self.previous) and self.predicted > 0:
            ratio = (smooth_before - self.previous) / self.predicted
            if ratio < SHRINK_BELOW:
                self.scale = max(self.scale / 2.0, SMALLEST)
            elif ratio > GROW_ABOVE:
                self.scale = min(self.scale * 2.0, LARGEST)
        return self.scale

    def record(self, smooth_before: float, smooth_after: float) -> None:
        """Remember this batch's mean ρ̂ and the gain its update promised."""
        self.previous, self.predicted = smooth_before, smooth_after - smooth_before

    def to_array(self) -> np.ndarray:
        """``[scale, previous, predicted]``, for saving with the agent."""
        return np.array([self.scale, self.previous, self.predicted])

    @classmethod
    def from_array(cls, values: np.ndarray) -> AdaptiveRadius:
        """The inverse of `to_array`."""
        scale, previous, predicted = (float(v) for v in values)
        return cls(scale, previous, predicted)
