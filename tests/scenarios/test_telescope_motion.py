"""The telescope's motion step: a probe of the sharpest views decides whether every view is
registered (static views are returned as they are, moving ones corrected)."""

import numpy as np

from metasensor.motion.synthetic import (
    dynamic_view,
    natural_scene,
    rigid_motion,
    smooth_random_motion,
)
from metasensor.scenarios.telescope import correct_if_moving

ORDER = [(r, c) for r in range(5) for c in range(5)]
REF = len(ORDER) // 2
SIDE = 65  # 13 x 13 sub-images, as the telescope's views


def _stack(motion, seed=0):
    scene = natural_scene((200, 200), 2, 1.0, seed=seed)[:2 * SIDE, :2 * SIDE]
    view, _ = dynamic_view(scene, 2, (SIDE, SIDE), ORDER, motion)
    stack = np.zeros((2, 2, SIDE, SIDE), np.float32)
    stack[0, 0], stack[0, 1], stack[1, 0] = view, 0.9 * view, 1.1 * view  # [1, 1]: no light
    return stack


def test_static_views_skip_the_correction():
    stack = _stack(rigid_motion((0, 0), REF))
    stack += 0.01 * np.random.default_rng(0).standard_normal(stack.shape).astype(np.float32)
    stack[1, 1] = 0
    before = stack.copy()
    out, info = correct_if_moving(stack, ORDER, REF, probe=2)
    assert info == {"probe_views": 2, "probe_moving_fraction": 0.0, "corrected": False}
    np.testing.assert_array_equal(out, stack)
    np.testing.assert_array_equal(stack, before)  # input not modified
    assert out is not stack and out.dtype == np.float32


def test_moving_views_are_corrected_after_the_probe():
    motion, _ = smooth_random_motion((200, 200), len(ORDER), 1.0, 25.0, seed=3)
    stack = _stack(motion)
    out, info = correct_if_moving(stack, ORDER, REF, probe=1)
    assert info["corrected"] and info["probe_views"] == 1 and info["probe_moving_fraction"] > 0.3
    assert np.mean(out[0, 0] != stack[0, 0]) > 0.3 and np.all(out[1, 1] == 0)
