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
PSF cache keeps one bank per mirror orbit, so each is computed once.

Which member is computed is fixed: the orbit's *canonical* member (the least of its eight cache
keys), whichever member is asked for first, and every member is served by exact flips of it.
A computation differs from its mirror image's flipped computation by float32 rounding (a few
1e-7 of its maximum); were the first member asked for the one computed, the bank a call
returns, and through it a simulated capture's noise draw, would depend on what the cache held
before. Hand-written: a bookkeeping of array flips, tested against directly computed banks.
"""

from __future__ import annotations

import threading

import numpy as np

__all__ = ["Symmetry", "SYMMETRIES", "cached_mirrored", "mirror_pupil", "mirror_function",
           "mirror_amplitude", "canonical_key", "unmirror_bank"]


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


def mirror_function(f, g: Symmetry):
    """The pupil function of :func:`mirror_pupil` ``(P, g)``, given P's ``f(rho_x, rho_y)``.

    Parameters
    ----------
    f : callable
        ``f(rho_x, rho_y)`` on arrays of pupil coordinates of any shape.
    g : Symmetry
        The element.

    Returns
    -------
    callable
        ``f_g`` with ``f_g`` sampled on a symmetric grid equal to ``mirror_pupil`` of ``f``
        sampled on it.
    """
    flip_y, flip_x, swap = g

    def flipped(x, y):
        return f(-x if flip_x else x, -y if flip_y else y)

    return (lambda x, y: flipped(y, x)) if swap else flipped


def mirror_amplitude(amplitude, g: Symmetry):
    """A pupil amplitude as :func:`metasensor.optics.pupil.pupil_amplitude` takes it (None, an
    ``(nnum, nnum)`` map in view coordinates, or a callable), mirrored by ``g``."""
    if amplitude is None:
        return None
    if callable(amplitude):
        return mirror_function(amplitude, g)
    return np.ascontiguousarray(mirror_pupil(np.asarray(amplitude), g))


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


def canonical_key(head: tuple, a_ref: np.ndarray, w_ref: np.ndarray, tail: tuple
                  ) -> tuple[str, Symmetry]:
    """The cache key of a pupil's mirror orbit and the element that maps the pupil onto the
    orbit's canonical member (the least of the eight keys).

    Parameters
    ----------
    head : tuple
        Key parts before the pupil (code version, computation, optical digest).
    a_ref, w_ref : numpy.ndarray
        The pupil's amplitude and wavefront [waves] on the cache's reference grid (symmetric
        about its centre), hashed as float32.
    tail : tuple
        Key parts after the pupil (the computation's other settings).

    Returns
    -------
    (str, Symmetry)
        The canonical member's key and ``g`` with ``mirror_pupil(pupil, g)`` that member.
    """
    from metasensor.optics import cache

    keys = [cache.cache_key(*head, mirror_pupil(a_ref, g).astype(np.float32),
                            mirror_pupil(w_ref, g).astype(np.float32), *tail)
            for g in SYMMETRIES]
    index = min(range(len(keys)), key=keys.__getitem__)
    return keys[index], SYMMETRIES[index]


_ORBIT_LOCKS: dict[str, threading.Lock] = {}
_ORBIT_LOCKS_GUARD = threading.Lock()


def _orbit_lock(name: str) -> threading.Lock:
    """This process's lock of the mirror orbit whose canonical key is ``name``."""
    with _ORBIT_LOCKS_GUARD:
        return _ORBIT_LOCKS.setdefault(name, threading.Lock())


def _served(bank: np.ndarray, g: Symmetry) -> np.ndarray:
    """The asked pupil's bank (or 2D PSF) from its canonical member's, ``g`` undone."""
    if bank.ndim == 2:  # one 2D PSF: the image mirrors alone
        return unmirror_bank(bank[None, None], g)[0, 0]
    return unmirror_bank(bank, g)


def cached_mirrored(head: tuple, a_ref: np.ndarray, w_ref: np.ndarray, tail: tuple,
                    folder, compute) -> np.ndarray:
    """A pupil's bank (or 2D PSF): its mirror orbit's canonical member
    (:func:`canonical_key`) from the PSF cache, else computed and stored, and flipped back.
    Threads of one process asking for members of one orbit at once compute it once (the others
    wait, then read the cache).

    Parameters
    ----------
    head, a_ref, w_ref, tail
        As :func:`canonical_key`.
    folder : pathlib.Path or None
        The cache folder (None: the default one).
    compute : callable
        ``compute(g) -> numpy.ndarray``, the result for the pupil ``mirror_pupil(pupil, g)``
        (run inside :func:`metasensor.optics.cache.computing`: the process's CPU seconds while
        it runs count in the cache's ``stats["compute_seconds"]``, once however many threads
        compute). It must evaluate the pupil the same way for every ``g`` (e.g. through
        :func:`mirror_function`), so that the canonical member's result does not depend on
        which member asked for it.

    Returns
    -------
    numpy.ndarray
        The bank ``(n, n, K, K)`` or 2D PSF ``(K, K)``. One hit or one miss is counted, in
        the cache's totals and under the computation's name (``head[1]``, e.g.
        ``"view_psfs"``: :func:`metasensor.optics.cache.count`).
    """
    from metasensor.optics import cache

    kind = str(head[1]) if len(head) > 1 else ""
    key, g = canonical_key(head, a_ref, w_ref, tail)
    _, hit = cache.load_first([key], folder, count=False)
    if hit is None:
        with _orbit_lock(key):
            _, hit = cache.load_first([key], folder, count=False)
            if hit is None:  # no other thread stored it meanwhile
                cache.count(kind, hit=False)
                with cache.computing():
                    out = compute(g)
                cache.store(key, out, folder)
                return _served(out, g)
    cache.count(kind, hit=True)
    return _served(hit, g)
