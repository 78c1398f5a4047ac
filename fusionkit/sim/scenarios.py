"""Ready-made simulated recordings: the demo's, and the scenarios that isolate one sensor error."""

from __future__ import annotations

import numpy as np

from ..types import Recording
from .motion import Rest, Rotate, Translate
from .noise import Noise
from .sensors import simulate

__all__ = ["demo_recordings"]


def demo_recordings(rate: float = 200.0, seed: int = 0) -> list[Recording]:
    """Three short noisy recordings for the demo: slow rotations, fast rotations, translations."""
    deg = np.pi / 180.0
    noise = Noise.mems()
    slow = [Rest(12.0), Rotate((0, 0, 1), 90 * deg, 4.0), Rotate((1, 0, 0), 45 * deg, 3.0), Rest(2.0),
            Rotate((0, 1, 0), -60 * deg, 4.0), Rotate((0, 0, 1), -90 * deg, 4.0), Rest(5.0)]
    fast = [Rest(12.0)] + [Rotate(ax, 120 * deg * s, 1.0) for s in (1, -1) for ax in ((1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0))] + [Rest(5.0)]
    trans = [Rest(12.0)] + [Translate(d, 0.5, 1.5) for d in ((1, 0, 0), (0, 1, 0), (0, 0, 1), (-1, 0, 0), (0, -1, 0), (0, 0, -1))] + [Rotate((0, 0, 1), 30 * deg, 2.0), Rest(5.0)]
    return [simulate(s, rate=rate, noise=noise, seed=seed + i, name=nm)
            for i, (nm, s) in enumerate((("slow-rotation", slow), ("fast-rotation", fast), ("translation", trans)))]
