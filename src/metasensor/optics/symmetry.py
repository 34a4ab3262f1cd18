"""The square lenslet grid's eight mirror symmetries, acting on pupils and on PSF banks.

The optics of :func:`metasensor.optics.psf.view_psfs` (square lenslets on a square grid over a
square pixel grid; circular or square lenslet apertures; a radial pupil amplitude, obstruction
and apodization) are unchanged by the dihedral group of the square: the mirrors ``x ↦ −x`` and
``y ↦ −y`` and the swap ``x ↔ y``, and their compositions. So the PSF bank of a mirrored
wavefront is the mirrored bank, with the views permuted the same way:

- pupil ``ρ_y ↦ −ρ_y``: ``H[u, v, y, x] ↦ H[n−1−u, v, −y, x]``;
- pupil ``ρ_x ↦ −ρ_x``: ``H[u, v, y, x] ↦ H[u, n−1−v, y, −x]``;
- pupil ``ρ_x ↔ ρ_y``: ``H[u, v, y, x] ↦ H[v, u, x, y]``.

(Axes ``[u, v, y, x]``: ``u`` indexes the pupil's y, ``v`` its x; a bank's centre sample is zero
displacement, so the image mirrors are exact array flips.) A lens whose aberrations are
symmetric over its field (any centred lens) repeats each bank at up to eight field points; the
PSF cache looks a bank up under all eight images of its pupil, so each is computed once.
Hand-written: a bookkeeping of array flips, tested against directly computed banks.
"""

from __future__ import annotations

import threading

import numpy as np

__all__ = ["Symmetry", "SYMMETRIES", "cached_mirrored", "mirror_pupil", "mirrored_lookup",
           "unmirror_bank"]


Symmetry = tuple[bool, bool, bool]
"""One element ``(flip_y, flip_x, swap)`` of the group: flip the pupil's y and/or x axis, then
swap the axes."""

SYMMETRIES: tuple[Symmetry, ...] = tuple((fy, fx, sw) for sw in (False, True)
                                         for fy in (False, True) for fx in (False, True))
"""The eight elements, the identity first."""


def mirror_pupil(pupil: np.ndarray, g: Symmetry) -> np.ndarray:
    """``g`` applied to a pupil map sampled on a grid symmetric about its centre.

    Parameters
    ----------
    pupil : numpy.ndarray
        ``(N, N)`` map, rows along the pupil's y, columns along its x (a ``meshgrid(...,
        indexing="xy")`` layout).
    g : Symmetry
        The element.

    Returns
    -------
    numpy.ndarray
        The mirrored map (a view where possible).
    """
    flip_y, flip_x, swap = g
    out = pupil[::-1 if flip_y else 1, ::-1 if flip_x else 1]
    return out.T if swap else out


def unmirror_bank(bank: np.ndarray, g: Symmetry) -> np.ndarray:
    """The bank of a pupil from the bank of its image under ``g`` (``g``'s inverse on banks:
    undo the swap, then the flips).

    Parameters
    ----------
    bank : numpy.ndarray
        ``(n, n, K, K)`` bank ``H[u, v, y, x]`` of the pupil ``mirror_pupil(P, g)``.
    g : Symmetry
        The element.

    Returns
    -------
    numpy.ndarray
        ``(n, n, K, K)`` bank of ``P``, a new contiguous array of ``bank``'s dtype.
    """
    flip_y, flip_x, swap = g
    out = bank.transpose(1, 0, 3, 2) if swap else bank
    ys = slice(None, None, -1 if flip_y else 1)
    xs = slice(None, None, -1 if flip_x else 1)
    return np.ascontiguousarray(out[ys, xs, ys, xs])


def mirrored_lookup(head: tuple, a_ref: np.ndarray, w_ref: np.ndarray, tail: tuple,
                    folder=None, count: bool = True) -> tuple[str, np.ndarray | None]:
    """The PSF cache's key of a pupil's result, and that result from the cache: its own, or a
    mirror image's undone, or None on a miss (:mod:`metasensor.optics.cache`).

    Parameters
    ----------
    head : tuple
        Key parts before the pupil (code version, computation, optical digest).
    a_ref, w_ref : numpy.ndarray
        The pupil's amplitude and wavefront [waves] on the cache's reference grid (symmetric
        about its centre), hashed as float32.
    tail : tuple
        Key parts after the pupil (the computation's other settings).
    folder : pathlib.Path or None
        The cache folder (None: the default one).
    count : bool
        Count the lookup's hit or miss in the cache's ``stats``.

    Returns
    -------
    (str, numpy.ndarray or None)
        The pupil's own key (to store a computed result under), and the cached bank
        ``(n, n, K, K)`` or 2D PSF ``(K, K)``. The mirror images' keys are hashed only after
        the pupil's own key missed.
    """
    from metasensor.optics import cache

    def key_of(g):
        return cache.cache_key(*head, mirror_pupil(a_ref, g).astype(np.float32),
                               mirror_pupil(w_ref, g).astype(np.float32), *tail)

    key = key_of(SYMMETRIES[0])
    index, hit = cache.load_first((key if i == 0 else key_of(g)
                                   for i, g in enumerate(SYMMETRIES)), folder, count)
    if hit is None or not index:
        return key, hit
    if hit.ndim == 2:  # one 2D PSF: the image mirrors alone
        return key, unmirror_bank(hit[None, None], SYMMETRIES[index])[0, 0]
    return key, unmirror_bank(hit, SYMMETRIES[index])


_ORBIT_LOCKS: dict[str, threading.Lock] = {}
_ORBIT_LOCKS_GUARD = threading.Lock()


def _orbit_lock(head: tuple, a_ref: np.ndarray, w_ref: np.ndarray, tail: tuple
                ) -> threading.Lock:
    """This process's lock of the pupil's mirror orbit (named by the least of its eight keys)."""
    from metasensor.optics import cache

    name = min(cache.cache_key(*head, mirror_pupil(a_ref, g).astype(np.float32),
                               mirror_pupil(w_ref, g).astype(np.float32), *tail)
               for g in SYMMETRIES)
    with _ORBIT_LOCKS_GUARD:
        return _ORBIT_LOCKS.setdefault(name, threading.Lock())


def cached_mirrored(head: tuple, a_ref: np.ndarray, w_ref: np.ndarray, tail: tuple,
                    folder, compute) -> np.ndarray:
    """A pupil's bank (or 2D PSF) from the PSF cache (:func:`mirrored_lookup`), else
    ``compute()``'d and stored under the pupil's key; threads of one process asking for members
    of one mirror orbit at once compute it once (the others wait, then read the cache).

    Parameters
    ----------
    head, a_ref, w_ref, tail, folder
        As :func:`mirrored_lookup`.
    compute : callable
        ``compute() -> numpy.ndarray``, the result for this pupil (run inside
        :func:`metasensor.optics.cache.computing`: the process's CPU seconds while it runs count
        in the cache's ``stats["compute_seconds"]``, once however many threads compute).

    Returns
    -------
    numpy.ndarray
        The bank ``(n, n, K, K)`` or 2D PSF ``(K, K)``. One hit or one miss is counted, in the
        cache's totals and under the computation's name (``head[1]``, e.g. ``"view_psfs"``:
        :func:`metasensor.optics.cache.count`).
    """
    from metasensor.optics import cache

    kind = str(head[1]) if len(head) > 1 else ""
    _, hit = mirrored_lookup(head, a_ref, w_ref, tail, folder, count=False)
    if hit is None:
        with _orbit_lock(head, a_ref, w_ref, tail):
            key, hit = mirrored_lookup(head, a_ref, w_ref, tail, folder, count=False)
            if hit is None:  # no other thread stored a member meanwhile
                cache.count(kind, hit=False)
                with cache.computing():
                    out = compute()
                cache.store(key, out, folder)
                return out
    cache.count(kind, hit=True)
    return hit
