"""Shared synthetic scenes for the motion tests (built at the view level, see
metasensor.motion.synthetic: cubic-spline sampling of a 2x finer scene, no inverse crime)."""

import functools

import numpy as np

from metasensor.motion.synthetic import natural_scene

P = 5
ORDER = [(r, c) for r in range(P) for c in range(P)]
REF = len(ORDER) // 2
SHAPE = (200, 200)


def psnr(a, b, mask):
    return float(10 * np.log10(1.0 / np.mean((a[mask] - b[mask]) ** 2)))


@functools.cache
def scene(seed):
    return natural_scene(SHAPE, 2, 1.0, seed=seed)
