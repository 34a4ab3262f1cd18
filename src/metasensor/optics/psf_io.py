"""PSF banks on disk (HDF5) and their figure, and the ``--zernike`` text format.

File layout (h5py): dataset ``"psf"`` float32 ``[u, v, y, x]``; attributes ``config`` (the
SystemConfig as JSON), ``zernike`` (Noll vector, waves), ``depth`` [m], ``subsample``,
``pixel_pitch`` [m] (sampling of the last two axes = pixel_pitch / subsample), ``axes``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from metasensor.config import ConfigError, SystemConfig
from metasensor.io.atomic import atomic_path

__all__ = ["save_psf", "load_psf", "plot_views", "parse_zernike", "read_npy", "load_matlab_psf",
           "is_matlab_psf"]


def read_npy(path: str | Path, what: str) -> np.ndarray:
    """A ``.npy`` array (no pickles); one ``ValueError`` line naming ``what`` and the file if it
    is empty, truncated or not a NumPy file."""
    try:  # mapped first: a header declaring more data than the file holds fails here
        arr = np.array(np.load(path, allow_pickle=False, mmap_mode="r"))
    except MemoryError:
        raise
    except Exception as exc:  # noqa: BLE001 - a damaged header raises EOFError, TokenError...
        text = " ".join(str(exc).split()) or "empty"
        raise ValueError(f"{what} {path}: not a readable .npy file ({text})") from None
    if arr.dtype.kind not in "buif":
        raise ValueError(f"{what} {path}: expected real numbers, got dtype {arr.dtype}")
    return arr


MAX_VIEW_SUM = 1e3  # a PSF view's sum (1 at most for a bank this package writes)
MAX_NOLL = 231  # Noll indices up to radial order 20
MAX_WAVES = 100.0  # |coefficient| in waves: beyond, the pupil sampling cannot follow


def check_zernike(z: np.ndarray, what: str) -> np.ndarray:
    """A Noll vector within :data:`MAX_NOLL` terms and :data:`MAX_WAVES` waves, or one
    ``ValueError`` line naming ``what``."""
    if z.shape[-1] > MAX_NOLL:
        raise ValueError(f"{what}: {z.shape[-1]} Noll terms; at most {MAX_NOLL} are supported")
    if z.size and np.abs(z).max() > MAX_WAVES:
        raise ValueError(f"{what}: a coefficient of {np.abs(z).max():.3g} waves; at most "
                         f"{MAX_WAVES:g} are meaningful")
    return z


def parse_zernike(text: str | None) -> np.ndarray | None:
    """``"4:0.5,7:-0.2"`` -> Noll vector (waves) with z[3] = 0.5, z[6] = -0.2; "" -> None.
    A path to a ``.npy`` file holding a 1-D Noll vector (e.g. ``simulate``'s ``wavefront.npy``)
    is read as that vector."""
    if text is None or not text.strip():
        return None
    if text.strip().lower().endswith(".npy"):
        path = Path(text.strip())
        if not path.is_file():
            raise FileNotFoundError(f"--zernike file not found: {path}")
        z = read_npy(path, "--zernike")
        if z.ndim != 1 or z.size == 0 or not np.isfinite(z).all():
            raise ValueError(f"--zernike {path}: expected a finite 1-D Noll vector, got shape "
                             f"{z.shape}")
        return check_zernike(np.asarray(z, dtype=np.float64), f"--zernike {path}")
    coeffs: dict[int, float] = {}
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        try:
            j_text, c_text = item.split(":")
            j, c = int(j_text), float(c_text)
        except ValueError:
            raise ValueError(
                f"--zernike must look like '4:0.5,7:-0.2' (Noll index:waves), got {text!r}"
            ) from None
        if not 1 <= j <= MAX_NOLL:
            raise ValueError(f"--zernike: Noll index must lie in 1..{MAX_NOLL}, got {j}")
        if not np.isfinite(c):
            raise ValueError(f"--zernike: coefficient of mode {j} is not finite")
        coeffs[j] = c
    if not coeffs:
        return None
    z = np.zeros(max(coeffs))
    for j, c in coeffs.items():
        z[j - 1] = c
    return check_zernike(z, "--zernike")


def save_psf(path: str | Path, psf: np.ndarray, cfg: SystemConfig, zernike=None,
             depth: float = 0.0, subsample: int = 1) -> Path:
    """Write a bank ``(nnum, nnum, K, K)`` to HDF5 atomically; returns the path."""
    psf = np.asarray(psf, dtype=np.float32)
    if psf.ndim != 4 or psf.shape[:2] != (cfg.nnum, cfg.nnum):
        raise ValueError(f"psf must have shape (nnum, nnum, K, K), got {psf.shape}")
    path = Path(path)
    from metasensor.io.h5 import atomic_h5

    with atomic_h5(path) as f:  # a full disk: one line naming the file, never a crash
        f.create_dataset("psf", data=psf, compression="gzip", compression_opts=4)
        f.attrs["config"] = cfg.to_json()
        f.attrs["zernike"] = np.zeros(0) if zernike is None else np.asarray(zernike, float)
        f.attrs["depth"] = float(depth)
        f.attrs["subsample"] = int(subsample)
        f.attrs["pixel_pitch"] = cfg.pixel_pitch
        f.attrs["axes"] = "u,v,y,x"
    return path


def load_psf(path: str | Path, with_attrs: bool = False):
    """Read a bank written by :func:`save_psf` -> (psf float32 [u, v, y, x], config), plus the
    file's attributes (``subsample``, ``zernike``, ``depth``, ...) as a dict if ``with_attrs``."""
    import h5py

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"PSF file not found: {path}")
    from metasensor.io.h5 import h5_errors

    try:
        with h5_errors(path, "HDF5 PSF file"), h5py.File(path, "r") as f:
            if "psf" not in f:
                raise ValueError(f"{path}: no dataset 'psf' (not a metasensor PSF file)")
            psf = np.asarray(f["psf"], dtype=np.float32)
            attrs = dict(f["psf"].attrs) | dict(f.attrs)
            cfg = SystemConfig.from_json(str(attrs["config"]))
    except OSError as exc:
        raise ValueError(f"{path}: not a readable HDF5 file ({exc})") from None
    except (KeyError, ConfigError) as exc:
        raise ValueError(f"{path}: missing or corrupt config attribute ({exc})") from None
    sub = np.ravel(attrs.get("subsample", 1))
    if sub.size != 1 or not np.issubdtype(sub.dtype, np.number) or not sub[0] >= 1:
        raise ValueError(f"{path}: attribute 'subsample' must be one positive integer, got "
                         f"{attrs.get('subsample')!r:.40}")
    sums = psf.reshape(*psf.shape[:2], -1).sum(-1, dtype=np.float64) if psf.ndim == 4 else None
    if sums is not None and not (np.isfinite(sums).all() and 0 < sums.max() <= MAX_VIEW_SUM):
        raise ValueError(f"{path}: not a usable PSF bank (largest view sum {np.max(sums):.3g}; "
                         f"a bank's views sum to at most 1, here {MAX_VIEW_SUM:g} is allowed)")
    if psf.ndim != 4 or psf.shape[:2] != (cfg.nnum, cfg.nnum):
        raise ValueError(f"{path}: psf shape {psf.shape} does not match nnum {cfg.nnum}")
    return (psf, cfg, attrs) if with_attrs else (psf, cfg)


def plot_views(psf: np.ndarray, cfg: SystemConfig, path: str | Path, title: str = "",
               subsample: int = 1) -> Path:
    """PNG of a 3 x 3 selection of views (centre, and ±r views along u and v, r = 0.6 of the
    pupil radius), each on its own linear scale; written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c = cfg.center
    r = max(1, min(c, int(round(0.6 * cfg.pupil_radius_px))))
    fig, axes = plt.subplots(3, 3, figsize=(8, 8), constrained_layout=True)
    k = psf.shape[-1]
    ext = k * cfg.pixel_pitch / subsample * 1e6 / 2  # half width in µm
    for i, du in enumerate((-r, 0, r)):
        for j, dv in enumerate((-r, 0, r)):
            u, v = c + du, c + dv
            ax = axes[i, j]
            ax.imshow(psf[u, v], cmap="magma", extent=(-ext, ext, ext, -ext))
            ax.set_title(f"view ({u}, {v})  sum {psf[u, v].sum():.3f}", fontsize=9)
            ax.tick_params(labelsize=7)
    fig.suptitle(title or f"phase-space PSFs [u, v]; axes in µm at the MLA (K = {k})")
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return path


# ----------------------------------------------------------------------------- authors' files
_MATLAB_NAME = "psf_z"
_OVERSAMPLE_NAMES = ("oversample", "OSR", "osr", "upsampling")


def is_matlab_psf(path: str | Path) -> bool:
    """True for an HDF5 (MATLAB v7.3) file holding the authors' PSF variable ``psf_z``."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return _MATLAB_NAME in f and "psf" not in f
    except Exception:  # noqa: BLE001 - h5py raises several kinds for damaged files: the
        return False  # metasensor reader then names the file and the problem


def load_matlab_psf(path: str | Path, nnum: int | None = None,
                    oversample: int | None = None) -> np.ndarray:
    """The authors' PSF file (MATLAB v7.3 = HDF5, variable ``psf_z`` of MATLAB size
    ``(y, x, u, v)``) as a bank ``[u, v, y, x]`` float32 on the pixel grid.

    MATLAB stores arrays column-major, so h5py reads ``psf_z`` with its axes reversed,
    ``(v, u, x, y)``; they are put back to ``(u, v, y, x)``. ``oversample``: point positions
    per pixel of an oversampled file (None: a scalar variable ``oversample``/``OSR`` in the file,
    else 1); the pixel-grid bank is the sub-lattice through the centre sample, times
    ``oversample²`` (the ``view_psfs(subsample=)`` convention: a fine point carries
    1/oversample² of a pixel's flux), cropped to an odd size. ``nnum``: checked against the
    file's view axes when given.
    """
    import h5py

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"PSF file not found: {path}")
    try:
        with h5py.File(path, "r") as f:
            if _MATLAB_NAME not in f:
                raise ValueError(f"{path}: no variable '{_MATLAB_NAME}' (not an authors' PSF "
                                 "file)")
            raw = np.asarray(f[_MATLAB_NAME], dtype=np.float32)
            if oversample is None:
                found = [n for n in _OVERSAMPLE_NAMES if n in f]
                oversample = int(np.ravel(f[found[0]][()])[0]) if found else 1
    except (OSError, RuntimeError, KeyError) as exc:
        raise ValueError(f"{path}: not a readable HDF5 (MATLAB v7.3) file ({exc})") from None
    if raw.ndim != 4 or raw.shape[0] != raw.shape[1]:
        raise ValueError(f"{path}: {_MATLAB_NAME} must be 4-D (y, x, u, v) with nnum x nnum "
                         f"views, got h5py shape {raw.shape}")
    bank = raw.transpose(1, 0, 3, 2)  # (v, u, x, y) -> (u, v, y, x)
    if nnum is not None and bank.shape[0] != nnum:
        raise ValueError(f"{path}: {bank.shape[0]} x {bank.shape[1]} views, nnum is {nnum}")
    if not np.isfinite(bank).all():
        raise ValueError(f"{path}: {_MATLAB_NAME} contains NaN or infinite values")
    s = int(oversample)
    if s < 1:
        raise ValueError(f"{path}: oversample must be >= 1, got {oversample}")
    cy, cx = bank.shape[2] // 2, bank.shape[3] // 2  # the point's sample
    if s > 1:
        bank = bank[:, :, cy % s::s, cx % s::s] * np.float32(s * s)
        cy, cx = cy // s, cx // s
    h = min(cy, cx, bank.shape[2] - 1 - cy, bank.shape[3] - 1 - cx)  # odd window, centred
    return np.ascontiguousarray(bank[:, :, cy - h:cy + h + 1, cx - h:cx + h + 1],
                                dtype=np.float32)
