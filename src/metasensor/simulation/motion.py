"""Scene dynamics during a scan: each frame sees the scene at its own time.

A :class:`Motion` describes how the scene at time ``tau`` (frames after the reference time) is
made from the reference scene (the one ``cap.truth`` shows). All speeds are per frame, in
scene pixels; the reference time defaults to the middle frame, ``(T − 1) / 2``. Components add up:

- ``shift = (vy, vx)``: rigid translation (the scene content moves by ``tau · shift``);
- ``rotation``: degrees per frame about ``centre`` (default: the scene centre), positive from
  +x towards +y;
- ``flow``: (2, H, W) non-rigid velocity field (vy, vx) per pixel: content at x moves to
  ``x + tau · flow(x)`` (first-order, for small displacements);
- a moving object over the (static or moving) background: ``obj`` (H, W) radiance and ``mask``
  (H, W) alpha in [0, 1] at the reference time, moving by ``tau · obj_shift``:
  ``scene_t = background_t · (1 − mask_t) + obj_t · mask_t``.

Resampling uses cubic splines (``scipy.ndimage.map_coordinates``); values are clipped at 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

__all__ = ["Motion"]


def _pair(value, name: str) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair of numbers (dy, dx), got {value!r}") from None
    if not (math.isfinite(a) and math.isfinite(b)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return a, b


@dataclass(frozen=True)
class Motion:
    """Per-frame scene motion (see the module docstring for the model and units)."""

    shift: tuple[float, float] = (0.0, 0.0)
    rotation: float = 0.0
    centre: tuple[float, float] | None = None
    flow: np.ndarray | None = None
    obj: np.ndarray | None = None
    mask: np.ndarray | None = None
    obj_shift: tuple[float, float] = (0.0, 0.0)
    reference: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "shift", _pair(self.shift, "shift"))
        object.__setattr__(self, "obj_shift", _pair(self.obj_shift, "obj_shift"))
        if not math.isfinite(float(self.rotation)):
            raise ValueError(f"rotation must be finite, got {self.rotation!r}")
        if (self.obj is None) != (self.mask is None):
            raise ValueError("a moving object needs both obj and mask")

    def check(self, shape: tuple[int, int]) -> None:
        """Raise ValueError if the arrays do not match a scene of ``shape``."""
        if self.flow is not None:
            flow = np.asarray(self.flow)
            if flow.shape != (2, *shape):
                raise ValueError(f"motion flow must have shape (2, {shape[0]}, {shape[1]}), "
                                 f"got {flow.shape}")
            if not np.isfinite(flow).all():
                raise ValueError("motion flow contains NaN or infinite values")
        for name in ("obj", "mask"):
            arr = getattr(self, name)
            if arr is not None and np.shape(arr) != tuple(shape):
                raise ValueError(f"motion {name} must have the scene's shape {shape}, "
                                 f"got {np.shape(arr)}")

    def reference_time(self, n_frames: int) -> float:
        return (n_frames - 1) / 2.0 if self.reference is None else float(self.reference)

    @property
    def moves_background(self) -> bool:
        return self.shift != (0.0, 0.0) or self.rotation != 0.0 or self.flow is not None

    def reference_scene(self, scene: np.ndarray) -> np.ndarray:
        """The scene at the reference time (object composited in place)."""
        scene = np.asarray(scene, dtype=np.float32)
        if self.obj is None:
            return scene.copy()
        m = np.clip(np.asarray(self.mask, dtype=np.float32), 0, 1)
        return scene * (1 - m) + np.asarray(self.obj, dtype=np.float32) * m

    def _background(self, scene: np.ndarray, tau: float) -> np.ndarray:
        if not self.moves_background or tau == 0:
            return scene
        h, w = scene.shape
        yy, xx = np.meshgrid(np.arange(h, dtype=np.float64), np.arange(w, dtype=np.float64),
                             indexing="ij")
        if self.flow is not None:  # content moves from x - tau*flow(x) to x
            flow = np.asarray(self.flow, dtype=np.float64)
            yy, xx = yy - tau * flow[0], xx - tau * flow[1]
        yy, xx = yy - tau * self.shift[0], xx - tau * self.shift[1]
        if self.rotation:
            cy, cx = ((h - 1) / 2, (w - 1) / 2) if self.centre is None else self.centre
            a = -math.radians(self.rotation * tau)  # inverse rotation: output -> source
            dy, dx = yy - cy, xx - cx
            yy = cy + math.sin(a) * dx + math.cos(a) * dy
            xx = cx + math.cos(a) * dx - math.sin(a) * dy
        out = ndimage.map_coordinates(scene, [yy, xx], order=3, mode="nearest")
        return np.maximum(out, 0).astype(np.float32)

    def scene_at(self, scene: np.ndarray, tau: float) -> np.ndarray:
        """The scene ``tau`` frames after the reference time, (H, W) float32."""
        scene = np.asarray(scene, dtype=np.float32)
        bg = self._background(scene, tau)
        if self.obj is None:
            return bg if bg is not scene else scene.copy()
        dy, dx = tau * self.obj_shift[0], tau * self.obj_shift[1]
        obj = ndimage.shift(np.asarray(self.obj, dtype=np.float32), (dy, dx), order=3,
                            mode="constant")
        m = ndimage.shift(np.clip(np.asarray(self.mask, dtype=np.float32), 0, 1), (dy, dx),
                          order=1, mode="constant")
        return np.maximum(bg * (1 - m) + obj * m, 0).astype(np.float32)
