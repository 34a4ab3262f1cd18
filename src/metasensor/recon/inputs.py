"""What ``metasensor reconstruct`` reads: the view stack, its system configuration (stored in
the views, a ``--config`` TOML or a ``--psf`` bank's file), the aberration over the field
(``--field-zernike`` or ``--system``) and the views' sensor origin."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import typer

__all__ = ["ReconInputs", "read_inputs", "read_psf_file"]


@dataclass(frozen=True)
class ReconInputs:
    """The inputs of one reconstruction, read and checked against each other.

    Attributes
    ----------
    config : SystemConfig
    stack : array
        ``(nnum, nnum, Ly, Lx)`` views (NumPy, memory-mapped, or zarr read block by block).
    bank : numpy.ndarray or None
        A given ``(nnum, nnum, K, K)`` PSF bank (``--psf``).
    bank_zernike : numpy.ndarray or None
        The Noll vector (waves) the given bank's file says it was made with.
    field_zernike : numpy.ndarray or None
        ``(by, bx, J)`` Noll vectors (waves) over the field.
    origin : list of float or None
        The views' stored sensor origin (row, col), realign's.
    noise : PoissonGaussian or None
        The views' Poisson–Gaussian noise from their stored metadata (``gain``, ``read_noise``:
        what ``simulate`` writes), None where they do not say.
    """

    config: Any
    stack: Any
    bank: np.ndarray | None = None
    bank_zernike: np.ndarray | None = None
    field_zernike: np.ndarray | None = None
    origin: list | None = None
    noise: Any = None


def read_psf_file(path: Path, with_attrs: bool = False):
    """PSF bank (nnum, nnum, K, K) and its SystemConfig from a ``metasensor psf`` HDF5 file
    (:func:`metasensor.optics.psf_io.load_psf`), plus its attributes if ``with_attrs``; refuses
    banks sampled finer than the pixels. An authors' MATLAB v7.3 file (``psf_z``) gives the
    bank on the pixel grid and no configuration (None)."""
    from metasensor.optics.psf_io import is_matlab_psf, load_matlab_psf, load_psf

    if is_matlab_psf(path):  # the authors' psf_z (MATLAB v7.3): no configuration inside
        bank = load_matlab_psf(path)
        return (bank, None, {"source": "matlab"}) if with_attrs else (bank, None)
    bank, cfg, attrs = load_psf(path, with_attrs=True)
    if int(np.ravel(attrs.get("subsample", 1))[0]) != 1:
        raise ValueError(f"{path}: PSF bank sampled at pixel_pitch/{attrs['subsample']}; "
                         "reconstruction needs subsample 1")
    return (bank, cfg, attrs) if with_attrs else (bank, cfg)


def _origin(value, views: Path):
    """A stored origin as [row, col] floats, or None (none stored, or malformed: named on
    stderr, and left out of the image's description)."""
    if value is None:
        return None
    try:
        pair = [] if isinstance(value, str | bytes | dict) else [float(v) for v in value]
    except (TypeError, ValueError):
        pair = []
    if len(pair) != 2 or not all(np.isfinite(pair)):
        typer.echo(f"note: {views} stores a malformed origin {value!r}; the image gets none",
                   err=True)
        return None
    return pair


def _config(views: Path, psf: Path | None, config: Path | None, bank_cfg):
    """The system configuration: ``--config``, else the given bank's, else the views'; each
    given one checked against the one the views store. A bank's configuration takes the
    views' scan (a bank does not depend on the scan)."""
    from metasensor.config import SystemConfig
    from metasensor.io.views import check_against_stored, read_config_from_views

    stored = read_config_from_views(views, strict=config is None and psf is None)
    cfg = SystemConfig.from_toml(config) if config is not None else bank_cfg
    if psf is not None and stored is not None:
        if cfg is None:  # a bank without a configuration (the authors' file): the views'
            cfg = stored
        if cfg.nnum != stored.nnum:
            raise ValueError(f"{psf}: PSF bank made for nnum {cfg.nnum}, but {views} has nnum "
                             f"{stored.nnum}")
        if cfg.scan != stored.scan:
            cfg = cfg.replace(scan=stored.scan)
    if cfg is not None and stored is not None:
        check_against_stored(cfg, stored, psf or config, views)
    cfg = stored if cfg is None else cfg
    if cfg is None:
        raise ValueError(f"{views}: no system configuration stored; pass --config cfg.toml")
    return cfg


def _field_zernike(field_zernike: Path | None, system: Path | None) -> np.ndarray | None:
    """``(by, bx, J)`` Noll vectors from ``--field-zernike`` (.npy) or ``--system`` (system.h5)."""
    from metasensor.optics.psf_io import read_npy

    if field_zernike is not None:
        if not field_zernike.is_file():
            raise FileNotFoundError(f"field Zernike file not found: {field_zernike}")
        return read_npy(field_zernike, "--field-zernike")
    if system is not None:
        from metasensor.dao.system_aberration import SystemAberration

        if not system.is_file():
            raise FileNotFoundError(f"system aberration file not found: {system}")
        return SystemAberration.load(system).zernike
    return None


def _bank_zernike(attrs: dict) -> np.ndarray | None:
    z = np.asarray(attrs.get("zernike", ()), dtype=np.float64).ravel()
    return z if z.size and np.isfinite(z).all() else None


def read_inputs(args) -> ReconInputs:
    """Read and cross-check the inputs named by ``args`` (a
    :class:`metasensor.recon.commands.ReconstructArgs`); refuses outputs that would replace an
    input (:func:`metasensor.io.guard.guard`)."""
    from metasensor.io.guard import guard, npy_argument
    from metasensor.io.views import read_views, stored_extras
    from metasensor.recon.outputs import RESULT_FILES

    views = args.views
    if not views.exists():
        raise FileNotFoundError(f"view stack not found: {views}")
    guard([views, args.psf, args.config, args.field_zernike, args.system,
           npy_argument(args.zernike)], [args.out / n for n in RESULT_FILES], folders=[args.out])
    bank, bank_cfg, attrs = (None, None, {}) if args.psf is None else read_psf_file(
        args.psf, with_attrs=True)
    cfg = _config(views, args.psf, args.config, bank_cfg)
    if bank is not None and bank.shape[0] != cfg.nnum:
        raise ValueError(f"{args.psf}: {bank.shape[0]} x {bank.shape[0]} views, but {views} "
                         f"has nnum {cfg.nnum}")
    big = views.suffix.lower() != ".zarr" and views.stat().st_size > 2**29
    stack = read_views(views, nnum=cfg.nnum, mmap=big)  # zarr: lazy, read block by block
    extras = stored_extras(views)
    return ReconInputs(config=cfg, stack=stack, bank=bank, bank_zernike=_bank_zernike(attrs),
                       field_zernike=_field_zernike(args.field_zernike, args.system),
                       origin=_origin(extras.get("origin"), views), noise=_stored_noise(extras))


def _stored_noise(extras: dict):
    """The Poisson–Gaussian model of views whose metadata hold their gain and read noise (in
    DN, as ``simulate`` writes them), else None (unreadable values are ignored)."""
    from metasensor.solvers.noise_model import PoissonGaussian

    if extras.get("units", "DN") != "DN":
        return None
    try:
        return PoissonGaussian.from_metadata(extras)
    except (TypeError, ValueError):
        return None
