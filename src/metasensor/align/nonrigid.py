"""Smooth non-rigid registration of images (control-point grid, L2 loss, Adam in PyTorch).

The paper (Methods, "Initial global aberration estimation") registers every view to the centre
view with a smooth shift map described by 20 × 15 × 2 control points over the field of view,
fitted with the Adam optimiser on an L2 loss. This module is that method, written by hand on top
of ``torch.nn.functional.interpolate`` weights (bicubic upsampling of the control grid,
align_corners) and ``torch.nn.functional.grid_sample`` (prefiltered cubic B-spline warping, four
bilinear fetches; unbiased for sub-pixel shifts). A coarse-to-fine pyramid widens the capture range.

Convention: a shift field ``s`` has shape ``(2, H, W)`` = ``(dy, dx)`` in pixels and means
``moving(y + dy, x + dx) ≈ reference(y, x)``; :func:`warp` samples an image at ``(y + dy, x + dx)``,
so ``warp(moving, register_nonrigid(moving, reference)) ≈ reference``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from metasensor.backend import resolve_device, to_numpy

__all__ = ["NonrigidOptions", "register_nonrigid", "register_nonrigid_batch", "warp", "dense_field"]


def _check_images(arr, name: str, ndim: int) -> np.ndarray:
    arr = np.asarray(arr)
    if arr.ndim != ndim:
        raise ValueError(f"{name} must be {ndim}-D, got shape {arr.shape}")
    if min(arr.shape[-2:]) < 4:
        raise ValueError(f"{name} must be at least 4 x 4 pixels, got {arr.shape[-2:]}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr


def _interp_matrix(n_out: int, n_in: int, device) -> torch.Tensor:
    """``(n_out, n_in)`` matrix of 1-D bicubic (align_corners) interpolation weights."""
    eye = torch.eye(n_in, dtype=torch.float32, device=device)[None, None]
    if n_in == 1:
        return torch.ones((n_out, 1), dtype=torch.float32, device=device)
    return F.interpolate(eye, size=(n_out, n_in), mode="bicubic", align_corners=True)[0, 0]


def dense_field(control: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """Bicubic (align_corners) upsampling of control points ``(N, 2, gy, gx)`` to ``(N, 2, H, W)``.

    The corner control points sit exactly on the corner pixels. Computed as the separable product
    ``My @ C @ Mx.T`` (identical to ``F.interpolate(..., "bicubic", align_corners=True)`` and much
    faster to differentiate).
    """
    gy, gx = control.shape[-2:]
    if (gy, gx) == tuple(shape):
        return control
    my = _interp_matrix(shape[0], gy, control.device)
    mx = _interp_matrix(shape[1], gx, control.device)
    return torch.einsum("hi,ncij,wj->nchw", my, control, mx)


def _base_grid(h: int, w: int, device) -> torch.Tensor:
    yy = torch.arange(h, device=device, dtype=torch.float32)
    xx = torch.arange(w, device=device, dtype=torch.float32)
    return torch.stack(torch.meshgrid(yy, xx, indexing="ij"))  # (2, H, W)


def _to_grid(pos: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """Pixel positions ``(N, 2, H', W')`` (y, x) → grid_sample grid (align_corners=True)."""
    gx = pos[:, 1] * (2.0 / max(w - 1, 1)) - 1.0
    gy = pos[:, 0] * (2.0 / max(h - 1, 1)) - 1.0
    return torch.stack((gx, gy), dim=-1)


def bspline_coefficients(img: torch.Tensor) -> torch.Tensor:
    """Cubic B-spline coefficients of ``img (N, C, H, W)`` (mirror boundary, scipy prefilter)."""
    from scipy.ndimage import spline_filter1d

    arr = img.detach().cpu().numpy().astype(np.float64)
    arr = spline_filter1d(arr, 3, axis=-1, mode="mirror")
    arr = spline_filter1d(arr, 3, axis=-2, mode="mirror")
    return torch.as_tensor(arr.astype(np.float32), device=img.device)


def _bspline_weights(u: torch.Tensor):
    """Two-tap form of the cubic B-spline (Sigg & Hadwiger 2005): weights and bilinear taps."""
    i = torch.floor(u)
    t = u - i
    t2, t3 = t * t, t * t * t
    w0 = (1 - t) ** 3 / 6
    w1 = (3 * t3 - 6 * t2 + 4) / 6
    w2 = (-3 * t3 + 3 * t2 + 3 * t + 1) / 6
    w3 = t3 / 6
    g0, g1 = w0 + w1, w2 + w3
    return g0, g1, i - 1 + w1 / g0, i + 1 + w3 / g1


def _sample_bspline(coef: torch.Tensor, pos: torch.Tensor) -> torch.Tensor:
    """Cubic B-spline interpolation of coefficients ``coef (N, C, H, W)`` at ``pos (N, 2, h, w)``
    with four bilinear fetches (one grid_sample call); exact and differentiable in ``pos``."""
    h, w = coef.shape[-2:]
    gy0, gy1, hy0, hy1 = _bspline_weights(pos[:, 0])
    gx0, gx1, hx0, hx1 = _bspline_weights(pos[:, 1])
    taps = [(hy0, hx0), (hy0, hx1), (hy1, hx0), (hy1, hx1)]
    grid = torch.cat([_to_grid(torch.stack(t, 1), h, w) for t in taps], dim=1)
    val = F.grid_sample(coef, grid, mode="bilinear", padding_mode="reflection",
                        align_corners=True)
    v00, v01, v10, v11 = torch.chunk(val, 4, dim=-2)
    gy0, gy1, gx0, gx1 = (g[:, None] for g in (gy0, gy1, gx0, gx1))
    return gy0 * (gx0 * v00 + gx1 * v01) + gy1 * (gx0 * v10 + gx1 * v11)


def _sample(img: torch.Tensor, shifts: torch.Tensor, mode: str = "bspline",
            coef: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Sample ``img (N, 1, H, W)`` at ``(y + dy, x + dx)``; returns the image and a validity mask.

    ``mode="bspline"`` (cubic B-spline, unbiased for sub-pixel shifts; pass ``coef`` to reuse the
    prefiltered coefficients), or a torch grid_sample mode ("bicubic" = Keys a = −0.75, which
    biases sub-pixel shifts of smooth images by a few hundredths of a pixel, "bilinear", ...).
    """
    n, _, h, w = img.shape
    pos = _base_grid(h, w, img.device)[None] + shifts  # (N, 2, H, W)
    if mode == "bspline":
        out = _sample_bspline(bspline_coefficients(img) if coef is None else coef, pos)
        m = 0.0
    else:
        out = F.grid_sample(img, _to_grid(pos, h, w), mode=mode, padding_mode="border",
                            align_corners=True)
        m = 1.0 if mode == "bicubic" else 0.0  # bicubic needs one neighbour beyond the sample
    valid = ((pos[:, 0] >= m) & (pos[:, 0] <= h - 1 - m) & (pos[:, 1] >= m)
             & (pos[:, 1] <= w - 1 - m))
    return out, valid[:, None].to(img.dtype)


def warp(image: np.ndarray, shifts: np.ndarray, mode: str = "bspline", device=None) -> np.ndarray:
    """Sample ``image`` at ``(y + dy, x + dx)``: image ``(H, W)`` or ``(N, H, W)``, shifts
    ``(2, H, W)`` or ``(N, 2, H, W)`` in pixels. Outside the image the border value is repeated.
    ``mode``: "bspline" (cubic B-spline, default), "bicubic", "bilinear" or "nearest".
    Returns float32, same shape as image.
    """
    image = np.asarray(image)
    shifts = np.asarray(shifts)
    single = image.ndim == 2
    if image.ndim not in (2, 3):
        raise ValueError(f"image must be (H, W) or (N, H, W), got {image.shape}")
    img = image[None] if single else image
    sh = shifts[None] if shifts.ndim == 3 else shifts
    if sh.ndim != 4 or sh.shape[1] != 2 or sh.shape[-2:] != img.shape[-2:]:
        raise ValueError(f"shifts must be (2, H, W) or (N, 2, H, W) matching the image "
                         f"{img.shape[-2:]}, got {shifts.shape}")
    if sh.shape[0] not in (1, img.shape[0]):
        raise ValueError(f"shifts batch {sh.shape[0]} does not match images {img.shape[0]}")
    dev = resolve_device(device)
    t_img = torch.as_tensor(np.array(img, dtype=np.float32), device=dev)[:, None]
    t_sh = torch.as_tensor(np.array(sh, dtype=np.float32), device=dev)
    if t_sh.shape[0] != t_img.shape[0]:
        t_sh = t_sh.expand(t_img.shape[0], -1, -1, -1)
    with torch.no_grad():
        out, _ = _sample(t_img, t_sh, mode=mode)
    out = to_numpy(out[:, 0])
    return out[0] if single else out


def _normalise(t: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """Zero mean, unit r.m.s. per image (over the mask), so the L2 loss and lr are scale-free."""
    dims = (-2, -1)
    if mask is None:
        mean = t.mean(dim=dims, keepdim=True)
        std = t.std(dim=dims, keepdim=True)
    else:
        wsum = mask.sum(dim=dims, keepdim=True).clamp_min(1.0)
        mean = (t * mask).sum(dim=dims, keepdim=True) / wsum
        std = (((t - mean) ** 2 * mask).sum(dim=dims, keepdim=True) / wsum).sqrt()
    return (t - mean) / std.clamp_min(1e-12)


@dataclass(frozen=True)
class NonrigidOptions:
    """Settings of :func:`register_nonrigid_batch` (frozen, validated).

    Attributes
    ----------
    grid : (int, int)
        Control points ``(rows, cols)`` (the paper: 15 × 20 over the field; (1, 1): rigid).
    iterations : int
        Adam steps per pyramid level.
    lr : float
        Adam step size in pixels of the full-resolution image.
    levels : int
        Pyramid levels (factor 2 each, coarse to fine; 1 = single scale).
    normalise : bool
        Compare zero-mean, unit-variance images (per image, over the mask).
    batch_size : int
        Images optimised together (memory bound; the result does not depend on it).
    """

    grid: tuple = (15, 20)
    iterations: int = 200
    lr: float = 0.05
    levels: int = 3
    normalise: bool = True
    batch_size: int = 16

    def __post_init__(self) -> None:
        if self.iterations < 1 or self.lr <= 0 or self.levels < 1 or self.batch_size < 1:
            raise ValueError("iterations, lr, levels and batch_size must be positive")
        object.__setattr__(self, "grid", (int(self.grid[0]), int(self.grid[1])))


def _batch_tensors(movings, reference, mask, init, grid, dev):
    """Moving, reference and mask tensors (N or 1, 1, H, W) and the initial control field."""
    n, h, w = movings.shape
    mov = torch.as_tensor(np.array(movings, dtype=np.float32), device=dev)[:, None]
    ref = torch.as_tensor(np.array(reference, dtype=np.float32), device=dev)
    ref = ref[None, None] if ref.ndim == 2 else ref[:, None]
    msk = None
    if mask is not None:
        mask = np.asarray(mask, dtype=np.float32)
        if mask.shape[-2:] != (h, w) or mask.ndim not in (2, 3):
            raise ValueError(
                f"mask must be (H, W) or (N, H, W) matching {(h, w)}, got {mask.shape}")
        msk = torch.as_tensor(np.array(mask), device=dev)
        msk = msk[None, None] if msk.ndim == 2 else msk[:, None]
    gy, gx = grid
    control = torch.zeros((n, 2, gy, gx), dtype=torch.float32, device=dev)
    if init is not None:
        init_t = torch.as_tensor(np.array(init, dtype=np.float32), device=dev)
        if init_t.shape[:2] != (n, 2) or init_t.ndim != 4:
            raise ValueError(f"init must be (N, 2, H, W) or (N, 2, rows, cols), got {init_t.shape}")
        if tuple(init_t.shape[-2:]) != (gy, gx):
            init_t = F.interpolate(init_t, size=(gy, gx), mode="bilinear", align_corners=True)
        control = init_t.clone()
    return mov, ref, msk, control


def register_nonrigid_batch(movings: np.ndarray, reference: np.ndarray,
                            options: NonrigidOptions | None = None, *,
                            mask: np.ndarray | None = None, init: np.ndarray | None = None,
                            device=None, tick=None, **settings) -> np.ndarray:
    """Register many images to one reference (or to one reference each) at once.

    Parameters
    ----------
    movings : array_like
        ``(N, H, W)``.
    reference : array_like
        ``(H, W)`` or ``(N, H, W)``.
    options : NonrigidOptions, optional
        ``settings`` (keywords named as its fields: ``grid``, ``iterations``, ``lr``, ...)
        override it.
    mask : array_like, optional
        ``(H, W)`` or ``(N, H, W)`` weights (> 0 where the loss counts).
    init : array_like, optional
        Starting field ``(N, 2, H, W)`` or ``(N, 2, rows, cols)`` control values.
    device : str, optional
    tick : callable, optional
        ``tick(n)`` called as Adam steps are done (for a caller's progress bar; 10 at a time,
        ``levels × iterations`` in all, fewer when a level is too small to fit).

    Returns
    -------
    numpy.ndarray
        float32 ``(N, 2, H, W)`` shift fields ``(dy, dx)`` in pixels such that
        ``moving(y + dy, x + dx) ≈ reference(y, x)`` (see :func:`warp`). Pixels whose sample
        falls outside the moving image do not count in the loss.
    """
    from dataclasses import replace

    opts = replace(options or NonrigidOptions(), **settings)
    movings = _check_images(movings, "movings", 3)
    reference = np.asarray(reference)
    reference = _check_images(reference, "reference", reference.ndim if reference.ndim in (2, 3)
                              else 2)
    n, h, w = movings.shape
    if reference.shape[-2:] != (h, w) or (reference.ndim == 3 and reference.shape[0] != n):
        raise ValueError(
            f"reference shape {reference.shape} does not match movings {movings.shape}")
    gy, gx = opts.grid
    if gy < 1 or gx < 1 or gy > h or gx > w:
        raise ValueError(
            f"grid must be (rows, cols) of control points within the image, got {opts.grid}")
    if n > opts.batch_size:
        def part(a, sl):
            a = None if a is None else np.asarray(a)
            return a[sl] if a is not None and a.ndim in (3, 4) and len(a) == n else a

        out = []
        for i in range(0, n, opts.batch_size):
            sl = slice(i, i + opts.batch_size)
            out.append(register_nonrigid_batch(movings[sl], part(reference, sl), opts,
                                               mask=part(mask, sl), init=part(init, sl),
                                               device=device, tick=tick))
        return np.concatenate(out)
    mov, ref, msk, control = _batch_tensors(movings, reference, mask, init, (gy, gx),
                                            resolve_device(device))
    control.requires_grad_(True)
    for level in reversed(range(opts.levels)):
        f = 2 ** level
        if min(h, w) // f < 8:
            continue
        control = _fit_level(mov, ref, msk, control, f, opts, tick)
    with torch.no_grad():
        out = dense_field(control, (h, w))
    return to_numpy(out).astype(np.float32)


def _fit_level(mov, ref, msk, control, f, opts: NonrigidOptions, tick=None):
    """Adam on the L2 loss at pyramid level ``f`` (average pooling by f); control in full-res px."""
    if f > 1:
        mov_l, ref_l = F.avg_pool2d(mov, f), F.avg_pool2d(ref, f)
        msk_l = F.avg_pool2d(msk, f) if msk is not None else None
    else:
        mov_l, ref_l, msk_l = mov, ref, msk
    iterations, lr = opts.iterations, opts.lr
    if opts.normalise:
        mov_l, ref_l = _normalise(mov_l, msk_l), _normalise(ref_l, msk_l)
    hl, wl = mov_l.shape[-2:]
    coef = bspline_coefficients(mov_l)
    # pooled pixel i covers full-res pixels [i f, (i + 1) f): centre at i f + (f - 1) / 2; the
    # field in level pixels is the full-res field / f (the offset cancels for a shift field).
    control = control.detach().clone().requires_grad_(True)
    opt = torch.optim.Adam([control], lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=iterations, eta_min=lr * 0.02)
    for k in range(iterations):
        if tick is not None and k % 10 == 9:
            tick(10)
        opt.zero_grad(set_to_none=True)
        field = dense_field(control, (hl, wl)) / f
        warped, valid = _sample(mov_l, field, coef=coef)
        wgt = valid if msk_l is None else valid * msk_l
        loss = (((warped - ref_l) ** 2) * wgt).sum(dim=(-3, -2, -1)) / wgt.sum(
            dim=(-3, -2, -1)).clamp_min(1.0)
        loss.sum().backward()
        opt.step()
        sched.step()
    return control.detach()


def register_nonrigid(moving: np.ndarray, reference: np.ndarray,
                      options: NonrigidOptions | None = None, *, mask: np.ndarray | None = None,
                      init: np.ndarray | None = None, device=None, **settings) -> np.ndarray:
    """Register one image ``moving (H, W)`` to ``reference (H, W)``.

    Returns the float32 shift field ``(2, H, W)`` = ``(dy, dx)`` in pixels with
    ``moving(y + dy, x + dx) ≈ reference(y, x)``. Parameters as :func:`register_nonrigid_batch`
    (``init``: ``(2, H, W)`` or ``(2, rows, cols)``).
    """
    moving = _check_images(moving, "moving", 2)
    reference = _check_images(reference, "reference", 2)
    if mask is not None and np.asarray(mask).ndim != 2:
        raise ValueError(f"mask must be (H, W), got {np.asarray(mask).shape}")
    init = None if init is None else np.asarray(init)[None]
    return register_nonrigid_batch(moving[None], reference, options, mask=mask, init=init,
                                   device=device, **settings)[0]
