"""The PSF bank of a mirrored pupil is the mirrored bank (optics/symmetry.py), and the PSF cache
serves it from the bank of the pupil's mirror image."""

import numpy as np
import pytest

from metasensor.config import SystemConfig
from metasensor.optics import cache as psf_cache
from metasensor.optics.psf import view_psfs
from metasensor.optics.symmetry import SYMMETRIES, mirror_pupil, unmirror_bank


def _phase(x, y):
    """An asymmetric wavefront [waves]: no mirror of the square maps it onto itself."""
    return 0.3 * x**3 + 0.2 * x * y**2 - 0.15 * y**3 + 0.25 * y + 0.1 * x * y + 0.05 * x


def _mirrored(g):
    """The phase whose samples on the cache's pupil grid are ``mirror_pupil(samples, g)``."""
    flip_y, flip_x, swap = g

    def flipped(x, y):
        return _phase(-x if flip_x else x, -y if flip_y else y)

    return (lambda x, y: flipped(y, x)) if swap else flipped


def _check_mirrors_served(compute, folder):
    """``compute(phase, cache)`` of the asymmetric phase, then of its seven mirror images: each
    a cache hit equal to its direct computation to 1e-6 of the maximum, and unequal to the
    first (the mirror is not trivial); one file in the cache. Returns the first result."""
    stats = psf_cache.stats
    base = compute(_phase, folder)
    for g in SYMMETRIES[1:]:
        hits = stats["hits"]
        served = compute(_mirrored(g), folder)
        assert stats["hits"] == hits + 1, g
        direct = compute(_mirrored(g), False)
        assert served.dtype == np.float32 and served.flags.c_contiguous
        np.testing.assert_allclose(served, direct, rtol=0, atol=1e-6 * direct.max())
        assert np.abs(direct - base).max() > 1e-3 * base.max()
    assert len(list((folder / "psf").glob("*.npy"))) == 1
    return base


def test_group_on_pupil_arrays():
    """The eight elements are distinct, the identity first, and each maps a grid symmetric
    about its centre onto itself (reference: index arithmetic)."""
    a = np.arange(25.0).reshape(5, 5)
    images = [mirror_pupil(a, g) for g in SYMMETRIES]
    assert np.array_equal(images[0], a)
    assert len({im.tobytes() for im in images}) == 8
    for g in SYMMETRIES:
        assert sorted(mirror_pupil(a, g).ravel()) == sorted(a.ravel())


@pytest.mark.parametrize("aperture, obstruction", [("circular", 0.0), ("square", 0.3)])
def test_cache_serves_the_mirror_images_of_a_bank(tmp_path, aperture, obstruction):
    """After one computed bank, the seven mirror images of its pupil are cache hits, and each
    equals its directly computed bank to 1e-6 of the maximum (float32 FFT rounding; measured
    about 2e-7 on the default 15 x 15 system)."""
    cfg = SystemConfig(nnum=3, mla_pitch=3 * 4.6e-6, mla_focal=3 * 46e-6, scan=3,
                       lenslet_aperture=aperture, obstruction=obstruction)
    _check_mirrors_served(lambda phase, cache: view_psfs(cfg, phase=phase, size=9, cache=cache),
                          tmp_path)


def test_unmirror_bank_inverts_the_view_and_image_mirrors():
    """unmirror_bank undoes, on a bank, the mirror that g makes of the pupil: for each g the
    bank of the mirrored pupil, unmirrored, is the pupil's own (the default 15 x 15 system, the
    asymmetric wavefront above; 1e-6 of the maximum)."""
    cfg = SystemConfig()
    base = view_psfs(cfg, phase=_phase, size=7, cache=False)
    for g in (SYMMETRIES[1], SYMMETRIES[2], SYMMETRIES[4], SYMMETRIES[7]):
        bank = view_psfs(cfg, phase=_mirrored(g), size=7, cache=False)
        np.testing.assert_allclose(unmirror_bank(bank, g), base, rtol=0,
                                   atol=1e-6 * base.max())


@pytest.mark.parametrize("kwargs", [{"subsample": 3, "band_limited": True}, {"points": 9}])
def test_mirror_images_hold_for_the_simulator_and_point_grids(kwargs):
    """The simulator's banks (3× sub-sampled, band-limited) and banks on another point grid
    obey the same mirrors: 2e-6 of the maximum (measured 1.2e-6 and 4.4e-7 on the default
    system; the band-limited bank's interpolation adds to float32 rounding)."""
    cfg = SystemConfig(nnum=3, mla_pitch=3 * 4.6e-6, mla_focal=3 * 46e-6, scan=3)
    base = view_psfs(cfg, phase=_phase, size=5, cache=False, **kwargs)
    for g in SYMMETRIES[1:]:
        bank = view_psfs(cfg, phase=_mirrored(g), size=5, cache=False, **kwargs)
        np.testing.assert_allclose(unmirror_bank(bank, g), base, rtol=0,
                                   atol=2e-6 * base.max())


def test_cache_serves_the_mirror_images_of_a_widefield_psf(tmp_path):
    """The 2D sensor's PSF of a mirrored pupil is the mirrored PSF: after one computed PSF the
    seven mirror images are cache hits, each equal to its direct computation to 1e-6 of the
    maximum (float64 field, float32 output)."""
    from metasensor.optics.widefield import widefield_psf

    cfg = SystemConfig(nnum=3, mla_pitch=3 * 4.6e-6, mla_focal=3 * 46e-6, scan=3)
    base = _check_mirrors_served(
        lambda phase, cache: widefield_psf(cfg, phase=phase, size=15, cache=cache), tmp_path)
    assert base.shape == (15, 15)


@pytest.mark.parametrize("which", ["view_psfs", "widefield_psf"])
def test_a_bank_does_not_depend_on_what_the_cache_held(tmp_path, which):
    """The same pupil asked of a fresh cache, and of a cache that first served each of its
    mirror images, gives the same bits (one computation per orbit, always the canonical
    member's), and the amplitude map and phase are mirrored with it."""
    from metasensor.optics.widefield import widefield_psf

    cfg = SystemConfig(nnum=3, mla_pitch=3 * 4.6e-6, mla_focal=3 * 46e-6, scan=3)
    amap = np.array([[1.0, 0.9, 0.8], [0.7, 1.0, 0.95], [0.6, 0.85, 0.75]])

    def ask(phase, amplitude, folder):
        if which == "view_psfs":
            return view_psfs(cfg, [0, 0, 0, 0.1], phase=phase, amplitude=amplitude,
                             size=9, cache=folder)
        return widefield_psf(cfg, [0, 0, 0, 0.1], phase=phase, amplitude=amplitude,
                             size=15, cache=folder)

    fresh = ask(_phase, amap, tmp_path / "fresh")
    for i, g in enumerate(SYMMETRIES[1:]):
        folder = tmp_path / f"after_{i}"
        ask(_mirrored(g), np.ascontiguousarray(mirror_pupil(amap, g)), folder)
        assert np.array_equal(ask(_phase, amap, folder), fresh), g
        assert len(list((folder / "psf").glob("*.npy"))) == 1
    direct = ask(_phase, amap, False)
    np.testing.assert_allclose(fresh, direct, rtol=0, atol=1e-6 * direct.max())


def test_cache_counts_each_computation_apart(tmp_path):
    """The views' banks and the 2D sensor's PSFs are counted apart (``kind_stats``), and the
    totals (``stats``) are their sum."""
    from metasensor.optics.widefield import widefield_psf

    cfg = SystemConfig(nnum=3, mla_pitch=3 * 4.6e-6, mla_focal=3 * 46e-6, scan=3)
    before = {k: dict(v) for k, v in psf_cache.kind_stats.items()}
    totals = psf_cache.stats["hits"], psf_cache.stats["misses"]

    def delta(kind):
        now, old = psf_cache.kind_stats.get(kind, {}), before.get(kind, {})
        return tuple(now.get(n, 0) - old.get(n, 0) for n in ("hits", "misses"))

    for _ in range(2):
        view_psfs(cfg, phase=_phase, size=9, cache=tmp_path)
    widefield_psf(cfg, phase=_phase, size=15, cache=tmp_path)
    assert delta("view_psfs") == (1, 1)
    assert delta("widefield_psf") == (0, 1)
    assert (psf_cache.stats["hits"] - totals[0], psf_cache.stats["misses"] - totals[1]) == (1, 2)


def test_threads_asking_for_one_mirror_orbit_compute_it_once(tmp_path, monkeypatch):
    """Two threads asking at once for a bank and its mirror image (the simulator's kernel
    prefetch does) compute one bank: one miss and one hit, one file, both results equal to
    their direct computations to 1e-6 of the maximum. The computation is slowed so that the
    second request arrives while the first is computing."""
    import threading
    import time

    from metasensor.optics import psf

    cfg = SystemConfig(nnum=3, mla_pitch=3 * 4.6e-6, mla_focal=3 * 46e-6, scan=3)
    computed, slow = [], psf._view_bank

    def counted(*args, **kwargs):
        computed.append(threading.get_ident())
        time.sleep(0.5)
        return slow(*args, **kwargs)

    monkeypatch.setattr(psf, "_view_bank", counted)
    hits, misses = psf_cache.stats["hits"], psf_cache.stats["misses"]
    phases = [_phase, _mirrored(SYMMETRIES[3])]
    out = [None, None]

    def ask(i):
        out[i] = view_psfs(cfg, phase=phases[i], size=9, cache=tmp_path)

    workers = [threading.Thread(target=ask, args=(i,)) for i in range(2)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    assert len(computed) == 1
    assert (psf_cache.stats["hits"] - hits, psf_cache.stats["misses"] - misses) == (1, 1)
    assert len(list((tmp_path / "psf").glob("*.npy"))) == 1
    monkeypatch.setattr(psf, "_view_bank", slow)
    for phase, got in zip(phases, out, strict=True):
        direct = view_psfs(cfg, phase=phase, size=9, cache=False)
        np.testing.assert_allclose(got, direct, rtol=0, atol=1e-6 * direct.max())
