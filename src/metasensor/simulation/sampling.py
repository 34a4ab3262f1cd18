"""The simulator's optical sampling: per-call kernel banks, and the scene blurred by them and
sampled at the lenslet centres of every scan phase (:func:`metasensor.simulation.capture.
simulate`'s clean views, and the comparison sensors' pixels)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from metasensor.simulation import kernels as kern
from metasensor.simulation.layers import add_zernike
from metasensor.simulation.render import Lattice, sampled_conv
from metasensor.simulation.turbulence import screen_phase

__all__ = ["KernelBanks", "RenderPlan", "accumulate", "clean_views", "prefetch_kernels",
           "time_weights"]


class KernelBanks:
    """Collapsed, cropped kernels per (component, frame), computed once per call.

    ``psf``: the fine view-bank provider (default :func:`metasensor.simulation.kernels.
    fine_view_bank`); ``upsample``: the scene model (:data:`kernels.UPSAMPLERS`)."""

    def __init__(self, cfg, device, upsample="spline", psf=None):
        self.cfg, self.device, self.upsample, self._cache = cfg, device, upsample, {}
        self.psf = kern.fine_view_bank if psf is None else psf

    def views(self, z, depth, phase=None, key=None, subsample: int = kern.SUBSAMPLE):
        """The views' kernels ``(nnum², k, k)`` of Noll vector ``z`` at ``depth`` (m), from
        fine banks at ``subsample`` (another value than the default needs the built-in
        provider)."""
        k = ("v", None if z is None else tuple(np.round(z, 12)), depth, key, subsample)
        if k not in self._cache:
            if subsample == kern.SUBSAMPLE:
                fine = self.psf(self.cfg, z, depth, phase=phase, device=self.device)
            elif self.psf is kern.fine_view_bank:
                fine = self.psf(self.cfg, z, depth, phase=phase, device=self.device,
                                subsample=subsample)
            else:
                raise ValueError(f"a PSF provider gives subsample-{kern.SUBSAMPLE} banks only; "
                                 f"turbulence.subsample={subsample} needs the built-in PSFs")
            coll = kern.collapse(fine, factor=subsample, upsample=self.upsample)
            self._cache[k] = kern.as_kernels(kern.crop_energy(coll), self.device)
        return self._cache[k]

    def widefield(self, z, depth, phase=None, key=None):
        """The conventional sensor's pixel-integrated kernel ``(1, k, k)``."""
        k = ("w", None if z is None else tuple(np.round(z, 12)), depth, key)
        if k not in self._cache:
            fine = kern.fine_widefield(self.cfg, z, depth, phase=phase, device=self.device)
            coll = kern.collapse(fine, integrate=True, upsample=self.upsample)
            self._cache[k] = kern.as_kernels(kern.crop_energy(coll), self.device)
        return self._cache[k]


@dataclass(frozen=True)
class RenderPlan:
    """What every rendering of one ``simulate`` call shares.

    Attributes
    ----------
    comps : list of Component
        Field blocks x depth layers (:func:`metasensor.simulation.layers.build_components`).
    grid : numpy.ndarray or None
        ``(by, bx, J)`` field Noll vectors at the block centres (None: uniform aberration).
    planes : numpy.ndarray or None
        The depth planes rendered (m, image side).
    banks : KernelBanks
    motion : Motion or None
    screens : numpy.ndarray or None
        Turbulence phase screens per frame (waves), None without turbulence.
    tref : float
        The reference time (frame index) the truth shows.
    key_every, subsample : int
        The turbulence's key-frame spacing and bank sub-sampling
        (:class:`~metasensor.simulation.turbulence.Turbulence`).
    """

    comps: list
    grid: np.ndarray | None
    planes: np.ndarray | None
    banks: KernelBanks
    motion: Any
    screens: np.ndarray | None
    tref: float
    key_every: int = 1
    subsample: int = kern.SUBSAMPLE


def time_weights(t: int, n_frames: int, every: int) -> list[tuple[int, float]]:
    """``[(key frame, weight), ...]`` of frame ``t`` of ``n_frames``: key frames are every
    ``every``-th frame and the last; between two of them the weights fall linearly (sum 1)."""
    if every <= 1 or t % every == 0 or t == n_frames - 1:
        return [(t, 1.0)]
    k0 = t - t % every
    k1 = min(k0 + every, n_frames - 1)
    a = (t - k0) / (k1 - k0)
    return [(k0, 1.0 - a), (k1, a)]


def prefetch_kernels(comps, kernel_of, device, progress=None) -> None:
    """Call ``kernel_of`` (a :class:`KernelBanks` method, which keeps what it computes) on every
    component first, as local block tasks (:func:`metasensor.recon.parallel.run_tasks`): on
    the CPU one component per torch thread at once, each on one thread; on CUDA one after
    another. ``progress``: callable(n) advanced by one per component."""
    from metasensor.recon.parallel import local_workers, run_tasks

    comps = list(comps)
    run_tasks(kernel_of, comps, lambda _kernel: None, scheduler="threads",
              num_workers=local_workers(len(comps), device), progress=progress)


def accumulate(image: np.ndarray, comps, kernel_of, rows: Lattice, cols: Lattice,
               out: torch.Tensor, device) -> None:
    """Add ``Σ_k kernel_of(k) ⊛ (w_k · image)`` over the components, sampled on ``rows`` x
    ``cols``, into ``out`` (channels, len(rows), len(cols))."""
    base = torch.from_numpy(np.ascontiguousarray(image)).to(device)
    for comp in comps:
        kk = kernel_of(comp)
        c = kk.shape[-1] // 2
        img = base if comp.weight is None else base * torch.from_numpy(comp.weight).to(device)
        y0, y1, x0, x1 = comp.box
        sampled_conv(img, kk, rows.restrict(y0 - c, y1 + c), cols.restrict(x0 - c, x1 + c),
                     out=out)


def clean_views(scene: np.ndarray, inp, plan: RenderPlan, progress: bool) -> np.ndarray:
    """The noise-free views ``(nnum, nnum, Ly·p, Lx·p)`` float32 in scene units.

    ``inp``: :class:`metasensor.simulation.inputs.SimInputs`. A static scene is sampled at all
    phases at once; a moving one (or one under turbulence) frame by frame, each at its own
    time."""
    cfg, focus, comps, banks = inp.cfg, inp.focus, plan.comps, plan.banks
    n, p, d = cfg.nnum, cfg.scan, cfg.scan_step_px
    ly, lx = inp.lenslets
    dev = banks.device
    motion, screens = plan.motion, plan.screens
    views = torch.zeros((n * n, ly * p, lx * p), dtype=torch.float32, device=dev)
    if motion is None and screens is None:
        rows, cols = Lattice(n // 2, d, ly * p), Lattice(n // 2, d, lx * p)

        def kernel_of(cp):
            return banks.views(add_zernike(cp.zernike, focus), cp.depth)

        with tqdm(total=len(comps), desc="kernels", disable=not progress) as shown:
            prefetch_kernels(comps, kernel_of, dev, shown.update)
        with tqdm(comps, desc="views", disable=not progress) as shown:  # closed on any error
            accumulate(scene, shown, kernel_of, rows, cols, views, dev)
    else:
        count = len(inp.order)
        for t, (r, c) in enumerate(tqdm(inp.order, desc="frames", disable=not progress)):
            img = scene if motion is None else motion.scene_at(scene, t - plan.tref)
            sub = torch.zeros((n * n, ly, lx), dtype=torch.float32, device=dev)
            keys = [(None, 1.0)] if screens is None else time_weights(t, count, plan.key_every)
            for key, wt in keys:
                phase = None if key is None else screen_phase(screens[key])
                accumulate(img if wt == 1.0 else img * np.float32(wt), comps,
                           lambda cp, ph=phase, k=key: banks.views(
                               add_zernike(cp.zernike, focus), cp.depth, ph, k,
                               plan.subsample if k is not None else kern.SUBSAMPLE),
                           Lattice(r * d + n // 2, n, ly), Lattice(c * d + n // 2, n, lx), sub, dev)
            views[:, r::p, c::p] = sub
    return views.reshape(n, n, ly * p, lx * p).cpu().numpy()
