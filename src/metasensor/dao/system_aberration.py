"""Global system-aberration calibration (paper, Methods: "Initial global aberration estimation").

Register every view to the centre view with a smooth non-rigid shift field (control-point grid,
default 15 × 20 = the paper's 20 × 15, Adam, L2; :mod:`metasensor.align.nonrigid`) on a
textured capture (e.g. a checkerboard). The shift of view (u, v) at field point p is the local
wavefront gradient of that sub-aperture relative to the centre view (docs/conventions.md):
fitting Zernike modes 4–45 to the shifts of all views (:func:`metasensor.dao.wavefront.
fit_shifts`) at the centre of every block gives the field-dependent wavefront map
``(by, bx, 45)``. The pupil amplitude per block comes from the angular intensity
(:mod:`metasensor.dao.pupil`). Saved as HDF5 (``system.h5``), used to initialise the
per-block DAO (``init``) or alone (``reconstruct(field_zernike=sa.zernike)``), and by the depth
stage to warp views (:meth:`SystemAberration.shift_maps`).

Registration convention: ``V_uv(p + s_uv(p)) ≈ V_c(p)``, so ``s_uv`` (view samples) is the
displacement the aberration gives view (u, v) relative to the centre view; × d = image pixels.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from metasensor.config import ConfigError, SystemConfig

__all__ = ["SystemAberration", "calibrate_system", "plot_wavefront_map"]

FORMAT = "metasensor-system-aberration-1"


@dataclass
class SystemAberration:
    """A global (field-dependent) system-aberration calibration.

    zernike : (by, bx, 45) Noll vectors (waves) at the block centres (modes 4–45).
    shift_grid : (nnum, nnum, 2, gy, gx) per-view (dy, dx) shifts in VIEW samples relative to the
        centre view, at a regular grid whose corner points sit on the corner view samples
        (measured for the used views, modelled from the wavefront map for the others).
    view_shape : (h, w) of the views the calibration was measured on.
    config : the system configuration.
    pupils : (by, bx, nnum, nnum) binary pupil amplitudes, or None.
    residual_rms : (by, bx) r.m.s. (image pixels) of the shift-fit residuals.
    """

    zernike: np.ndarray
    shift_grid: np.ndarray
    view_shape: tuple[int, int]
    config: SystemConfig
    pupils: np.ndarray | None = None
    residual_rms: np.ndarray | None = None

    @property
    def blocks(self) -> tuple[int, int]:
        return tuple(self.zernike.shape[:2])

    def shift_maps(self, shape: tuple[int, int] | None = None) -> np.ndarray:
        """Dense per-view shift maps ``(nnum, nnum, 2, H, W)`` float32 in view pixels over the
        whole field, resampled (bicubic, corner-aligned) to ``shape`` (default: view_shape)."""
        import torch

        h, w = self.view_shape if shape is None else (int(shape[0]), int(shape[1]))
        if h < 1 or w < 1:
            raise ValueError(f"shape must be positive, got {shape}")
        n = self.shift_grid.shape[0]
        g = torch.as_tensor(self.shift_grid.reshape(n * n * 2, 1, *self.shift_grid.shape[-2:]),
                            dtype=torch.float32, device="cpu")
        if g.shape[-2:] == (1, 1):
            out = g.expand(-1, -1, h, w)
        else:
            out = torch.nn.functional.interpolate(g, size=(h, w), mode="bicubic",
                                                  align_corners=True)
        return out.reshape(n, n, 2, h, w).numpy().astype(np.float32)

    # ------------------------------------------------------------------ file I/O
    def save(self, path: str | Path) -> Path:
        """Write HDF5 atomically (datasets zernike, shift_grid, pupils, residual_rms; the config
        and view shape as attributes)."""

        from metasensor.io.h5 import atomic_h5

        path = Path(path)
        with atomic_h5(path) as f:  # a full disk: one line naming the file, never a crash
            f.attrs["format"] = FORMAT
            f.attrs["config"] = self.config.to_json()
            f.attrs["view_shape"] = np.asarray(self.view_shape, dtype=np.int64)
            f.create_dataset("zernike", data=np.asarray(self.zernike, np.float64))
            f.create_dataset("shift_grid", data=np.asarray(self.shift_grid, np.float32))
            if self.pupils is not None:
                f.create_dataset("pupils", data=np.asarray(self.pupils, np.float32))
            if self.residual_rms is not None:
                f.create_dataset("residual_rms", data=np.asarray(self.residual_rms, np.float64))
        return path

    @classmethod
    def load(cls, path: str | Path) -> SystemAberration:
        """Read a file written by :meth:`save` (clear errors for missing or foreign files)."""
        import h5py

        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"system calibration not found: {path}")
        from metasensor.io.h5 import h5_errors

        try:
            f = h5py.File(path, "r")
        except OSError as exc:
            raise ValueError(f"{path} is not a readable HDF5 file ({exc})") from None
        with h5_errors(path, "system-aberration file"), f:
            if f.attrs.get("format") != FORMAT:
                raise ValueError(f"{path} is not a metasensor system-aberration file")
            try:
                cfg = SystemConfig.from_json(str(f.attrs["config"]))
                out = cls(zernike=f["zernike"][()], shift_grid=f["shift_grid"][()],
                          view_shape=tuple(int(s) for s in f.attrs["view_shape"]), config=cfg,
                          pupils=f["pupils"][()] if "pupils" in f else None,
                          residual_rms=f["residual_rms"][()] if "residual_rms" in f else None)
            except (KeyError, ConfigError) as exc:
                raise ValueError(f"{path}: incomplete system calibration ({exc})") from None
        n = cfg.nnum
        if out.zernike.ndim != 3 or out.shift_grid.shape[:3] != (n, n, 2):
            raise ValueError(f"{path}: inconsistent shapes {out.zernike.shape}, "
                             f"{out.shift_grid.shape}")
        return out


def _block_means(field: np.ndarray, blocks: tuple[int, int], core: float = 0.5) -> np.ndarray:
    """Mean of ``(..., h, w)`` over the central ``core`` fraction (per axis) of each block of a
    by × bx grid of equal blocks → ``(..., by, bx)``: the value at the block centre of a field
    that varies linearly across it."""
    by, bx = blocks
    ys = np.array_split(np.arange(field.shape[-2]), by)
    xs = np.array_split(np.arange(field.shape[-1]), bx)

    def centre(idx):
        m = max(1, int(round(len(idx) * core)))
        a = (len(idx) - m) // 2
        return idx[a], idx[a + m - 1] + 1

    out = np.empty((*field.shape[:-2], by, bx), dtype=np.float64)
    for i, yy in enumerate(ys):
        y0, y1 = centre(yy)
        for j, xx in enumerate(xs):
            x0, x1 = centre(xx)
            out[..., i, j] = field[..., y0:y1, x0:x1].mean(axis=(-2, -1))
    return out


def _view_fields(v: np.ndarray, cfg: SystemConfig, used: np.ndarray, reg, device,
                 progress: bool) -> np.ndarray:
    """Displacement fields ``(n, n, 2, h, w)`` (view pixels) of the used views against the
    centre view (smooth non-rigid registration, 16 views at a time, the bar ticking every 10
    Adam steps); zero elsewhere."""
    from tqdm.auto import tqdm

    from metasensor.align.nonrigid import register_nonrigid_batch

    n, h, w = cfg.nnum, v.shape[2], v.shape[3]
    c = cfg.center
    gy, gx = reg.grid
    uv = np.argwhere(used)
    fields = np.zeros((n, n, 2, h, w), np.float32)
    chunk = 16  # register_nonrigid_batch's own batch: the same computation, 16 views a tick
    per_view = 1.0 / (reg.levels * reg.iterations)
    with tqdm(total=len(uv), desc="registering views", unit="view",
              disable=not progress) as bar:
        for a in range(0, len(uv), chunk):
            sel = uv[a:a + chunk]
            end = a + len(sel)

            def tick(k, m=len(sel), end=end):
                bar.update(min(k * m * per_view, end - bar.n))

            fields[sel[:, 0], sel[:, 1]] = register_nonrigid_batch(
                v[sel[:, 0], sel[:, 1]], v[c, c], reg, grid=(min(gy, h), min(gx, w)),
                device=device, tick=tick)
            bar.update(end - bar.n)  # levels too small to fit are skipped
    return fields


def calibrate_system(views, cfg: SystemConfig, blocks: tuple[int, int] = (4, 4),
                     threshold: float = 0.5, *, view_mask=None, device=None,
                     progress: bool = False, **registration) -> SystemAberration:
    """Global calibration from the views of a textured, in-focus target (module docstring).

    Parameters
    ----------
    views : array_like
        ``(nnum, nnum, h, w)`` view stack.
    cfg : SystemConfig
    blocks : (int, int)
        Blocks ``(by, bx)`` whose centres get a Noll vector.
    threshold : float
        Pupil binarisation threshold in (0, 1) (:mod:`metasensor.dao.pupil`).
    view_mask : array_like, optional
        ``(nnum, nnum)`` views to register (default ``cfg.view_mask()``).
    device : str, optional
    progress : bool
    **registration
        :class:`metasensor.align.nonrigid.NonrigidOptions` fields of the per-view registration
        (``grid`` control points, default 15 × 20; ``iterations`` Adam steps per level, 200).

    Returns
    -------
    SystemAberration
    """
    from metasensor.align.nonrigid import NonrigidOptions
    from metasensor.dao.pupil import estimate_block_pupils
    from metasensor.dao.wavefront import fit_shifts, gradient_matrix

    n = cfg.nnum
    v = np.asarray(views, dtype=np.float32)
    if v.ndim != 4 or v.shape[:2] != (n, n):
        raise ValueError(f"views must have shape ({n}, {n}, h, w), got {v.shape}")
    if not np.isfinite(v).all():
        raise ValueError("views contain NaN or infinite values")
    by, bx = (int(b) for b in blocks)
    h, w = v.shape[2:]
    if by < 1 or bx < 1 or by > h or bx > w:
        raise ValueError(f"blocks must be positive and at most the view size, got {blocks}")
    reg = NonrigidOptions(**registration)
    gy, gx = reg.grid
    if gy < 1 or gx < 1:
        raise ValueError(f"grid must be positive, got {reg.grid}")
    d = cfg.scan_step_px
    matrix = gradient_matrix(cfg)
    used = cfg.view_mask() if view_mask is None else np.asarray(view_mask, bool)
    used = used & (matrix[1] >= 0.5)
    pupils = estimate_block_pupils(v, cfg, (by, bx), threshold)
    lit = pupils.min(axis=(0, 1)) > 0
    used = used & lit
    c = cfg.center
    fields = _view_fields(v, cfg, used, reg, device, progress)
    # block averages of the measured shifts → image pixels → Zernike per block
    means = _block_means(fields, (by, bx)) * d  # (n, n, 2, by, bx)
    zern = np.zeros((by, bx, 45))
    resid = np.zeros((by, bx))
    for i in range(by):
        for j in range(bx):
            fit = fit_shifts(means[..., i, j], cfg, mask=used & (pupils[i, j] > 0),
                             matrix=matrix)
            zern[i, j] = fit.zernike
            resid[i, j] = fit.residual_rms
    # the shift grid: measured fields averaged onto a gy × gx corner-aligned grid
    ys = np.linspace(0, h - 1, min(gy, h))
    xs = np.linspace(0, w - 1, min(gx, w))
    iy = np.clip(np.rint(ys).astype(int), 0, h - 1)
    ix = np.clip(np.rint(xs).astype(int), 0, w - 1)
    shift_grid = fields[:, :, :, iy][:, :, :, :, ix]
    # views not measured: the wavefront model (relative to the centre view), per block
    model = np.einsum("uvcj,yxj->uvcyx", matrix[0], zern)  # (n, n, 2, by, bx) pixels
    model = (model - model[c, c][None, None]) / d
    byi = np.clip(((ys + 0.5) / h * by).astype(int), 0, by - 1)
    bxi = np.clip(((xs + 0.5) / w * bx).astype(int), 0, bx - 1)
    modelled = model[:, :, :, byi][:, :, :, :, bxi]
    shift_grid = np.where(used[:, :, None, None, None], shift_grid, modelled).astype(np.float32)
    return SystemAberration(zernike=zern, shift_grid=shift_grid, view_shape=(h, w), config=cfg,
                            pupils=pupils, residual_rms=resid)


def plot_wavefront_map(sa: SystemAberration, path: str | Path, truth=None) -> Path:
    """Figure like the paper's Fig. 2c: the wavefront (waves) of every block, laid out over the
    field (and the true map beside it when ``truth`` (by, bx, J) is given)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from metasensor.optics.zernike import wavefront

    maps = [("estimated", sa.zernike)] + ([("true", np.asarray(truth))] if truth is not None
                                           else [])
    by, bx = sa.blocks
    t = np.linspace(-1, 1, 65)
    x, y = np.meshgrid(t, t)
    inside = x**2 + y**2 <= 1
    fig, axes = plt.subplots(by, bx * len(maps), figsize=(1.6 * bx * len(maps), 1.6 * by),
                             squeeze=False)
    vmax = max(float(np.abs(wavefront(np.where(np.arange(z.shape[-1]) >= 3, z[i, j], 0), x,
                                      y)[inside]).max())
               for _, z in maps for i in range(by) for j in range(bx))
    for k, (name, z) in enumerate(maps):
        for i in range(by):
            for j in range(bx):
                zz = np.array(z[i, j], dtype=np.float64)
                zz[:3] = 0
                img = np.where(inside, wavefront(zz, x, y), np.nan)
                ax = axes[i, k * bx + j]
                im = ax.imshow(img, cmap="RdBu_r", vmin=-vmax, vmax=vmax)
                ax.set_xticks([])
                ax.set_yticks([])
                if i == 0 and j == 0:
                    ax.set_title(name, fontsize=8, loc="left")
    fig.colorbar(im, ax=axes, shrink=0.6, label="waves")
    from metasensor.io.figures import save_figure

    return save_figure(fig, path, tight=False)
