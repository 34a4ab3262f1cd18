"""Wave-optics PSFs against analytic references (each test states reference and tolerance)."""

import numpy as np
import pytest
from scipy.special import j0, j1

from metasensor.config import SystemConfig
from metasensor.optics import cache as psf_cache
from metasensor.optics.psf import view_psfs
from metasensor.optics.pupil import disk_fraction
from metasensor.optics.widefield import widefield_psf
from metasensor.optics.zernike import zernike_basis


def centroid(img, centre, half):
    """Energy centroid (y, x) of img inside the (2 half + 1)² window at integer centre (y, x),
    in pixels relative to the array centre K // 2."""
    cy, cx = centre
    win = img[cy - half:cy + half + 1, cx - half:cx + half + 1].astype(np.float64)
    t = np.arange(-half, half + 1)
    e = win.sum()
    k = img.shape[-1] // 2
    return (cy - k + (win.sum(1) @ t) / e, cx - k + (win.sum(0) @ t) / e)


@pytest.fixture(scope="module")
def bank0(small_cfg):
    return view_psfs(small_cfg, size=45)


# ----------------------------------------------------------------------------- widefield
def test_widefield_airy_ring_and_encircled_energy():
    """Aberration-free widefield PSF = Airy pattern. References: first dark ring at
    0.6098 λ/NA (tolerance 2 %); encircled energy 1 − J0²(v) − J1²(v), v = 2π NA r / λ,
    within 1 % (absolute) from 0.25 λ/NA out to the third dark ring (1.619 λ/NA).
    Sampling λ/(30 NA), so the pixel integration is negligible."""
    cfg = SystemConfig()
    lam_na = cfg.wavelength / cfg.na
    s = lam_na / 30
    psf = widefield_psf(cfg, sampling=s, size=151).astype(np.float64)
    k = psf.shape[0] // 2
    row = psf[k, k:]
    i = 12 + int(np.argmin(row[12:25]))  # first minimum along +x (0.4 - 0.8 λ/NA)
    a, b, c = row[i - 1], row[i], row[i + 1]
    r_min = (i + 0.5 * (a - c) / (a - 2 * b + c)) * s
    assert r_min == pytest.approx(0.6098 * lam_na, rel=0.02)
    yy, xx = np.mgrid[-k:k + 1, -k:k + 1] * s
    for r in np.linspace(0.25, 1.619, 12) * lam_na:
        v = 2 * np.pi * cfg.na * r / cfg.wavelength
        ee = np.sum(psf * disk_fraction(xx / r, yy / r, s / r))  # pixels weighted by area in r
        assert ee == pytest.approx(1 - j0(v) ** 2 - j1(v) ** 2, abs=0.01), r / lam_na


def test_widefield_default_window_and_sum():
    """Default size keeps >= 99.5 % of the light (sum in [0.995, 1.0005]); centre is the peak."""
    cfg = SystemConfig()
    psf = widefield_psf(cfg)
    k = psf.shape[0] // 2
    assert psf.shape[0] % 2 == 1 and psf.dtype == np.float32
    assert 0.995 <= psf.sum() <= 1.0005
    assert np.unravel_index(np.argmax(psf), psf.shape) == (k, k)
    # annular pupil (obstruction 0.3): the light reaching the image is 1 − 0.3² = 0.91, of
    # which the default window keeps >= 99.5 % (less the sampled edges' 0.2 %): [0.99, 1.001]
    ann = widefield_psf(cfg.replace(obstruction=0.3))
    assert 0.99 * 0.91 <= ann.sum() <= 1.001 * 0.91


@pytest.mark.parametrize("mode, axis", [(2, 1), (3, 0)])
def test_widefield_tilt_shift(mode, axis):
    """Noll-2 tilt of c waves, W = 2c·rho_x: U(r) = ∫P exp(i2π(2c rho_x − (NA/λ) rho·r)) peaks
    at x = 2cλ/NA (conventions.md forward transform); Noll 3 likewise along +y (rows).
    c = 0.35 waves -> +1.598 px at 4.6 um pixels; tolerance 0.1 px (centroids over a ±12 px
    window centred on the nearest pixel of each PSF's expected centre)."""
    cfg = SystemConfig()
    c = 0.35
    z = np.zeros(mode)
    z[mode - 1] = c
    shift = 2 * c * cfg.wavelength / cfg.na / cfg.pixel_pitch
    p0 = widefield_psf(cfg, size=61)
    p1 = widefield_psf(cfg, z, size=61)
    k = 30
    ctr1 = [k, k]
    ctr1[axis] += int(round(shift))
    got = np.array(centroid(p1, ctr1, 12)) - np.array(centroid(p0, (k, k), 12))
    want = np.zeros(2)
    want[axis] = shift
    assert np.abs(got - want).max() < 0.1


# ----------------------------------------------------------------------------- view PSFs
def test_bank_shape_dtype_symmetries(bank0, small_cfg):
    """Aberration-free, circular lenslets: the system is symmetric under y -> -y (view
    u -> 2c − u), x -> -x (v -> 2c − v) and x <-> y (transpose). Mirror views equal within
    1e-4 of the bank maximum."""
    h = bank0
    n = small_cfg.nnum
    assert h.shape == (n, n, 45, 45) and h.dtype == np.float32
    scale = h.max()
    assert np.abs(h - h[::-1, :, ::-1, :]).max() < 1e-4 * scale
    assert np.abs(h - h[:, ::-1, :, ::-1]).max() < 1e-4 * scale
    assert np.abs(h - h.transpose(1, 0, 3, 2)).max() < 1e-4 * scale


def test_bank_energy_equals_light_through_apertures(bank0, small_cfg):
    """conventions.md: Σ H = nnum² × (fraction of a lenslet passed by its aperture) = π/4·nnum²
    (circular) or nnum² (square); tolerance 1 % (the 45-px window keeps > 99 %)."""
    assert bank0.sum() == pytest.approx(np.pi / 4 * small_cfg.nnum**2, rel=0.01)
    sq = view_psfs(small_cfg.replace(lenslet_aperture="square"), size=45)
    assert sq.sum() == pytest.approx(small_cfg.nnum**2, rel=0.01)


def test_views_outside_pupil_are_dark():
    """A pupil image smaller than the lenslet (NA·f_ml/pitch = 2.5 px, nnum = 9): views whose
    pixel lies >= 1.5 px beyond the pupil image's edge carry < 1 % of the centre view's energy
    (lenslet diffraction blur λ·f/D = 0.63 px). Note: with the prototype's matched f-numbers
    no view is that far out; its corner views hold ~5 % (edge diffraction of the lenslets)."""
    cfg = SystemConfig(nnum=9, mla_pitch=9 * 4.6e-6, mla_focal=230e-6, scan=3)
    e = view_psfs(cfg, size=27).sum(axis=(2, 3))
    u = np.arange(9) - 4
    dist = np.hypot(u[:, None], u[None, :])
    outside = dist - 0.5 >= cfg.pupil_radius_px + 1.5
    assert outside.sum() >= 8
    assert e[outside].max() < 0.01 * e[4, 4]
    assert e[4, 4] > 0.9  # the centre view is bright


def _tilt(c, mode):
    z = np.zeros(mode)
    z[mode - 1] = c
    return z


@pytest.mark.parametrize("mode, axis", [(2, 1), (3, 0)])
def test_view_tilt_shift(bank0, small_cfg, mode, axis):
    """Noll 2 (3) tilt of c waves shifts every view PSF by +2cλ/NA along +x (+y) on the MLA:
    c = 0.3 waves -> 1.370 px. Centroids in ±15 px windows (at the nearest pixel of the
    expected centre), tilted minus untilted, for all views inside the pupil; tol 0.1 px."""
    cfg = small_cfg
    c = 0.3
    shift = 2 * c * cfg.wavelength / cfg.na / cfg.pixel_pitch
    h1 = view_psfs(cfg, _tilt(c, mode), size=45)
    k = 22
    ctr1 = [k, k]
    ctr1[axis] += int(round(shift))
    mask = cfg.view_mask()
    want = np.zeros(2)
    want[axis] = shift
    for u, v in zip(*np.nonzero(mask), strict=True):
        got = np.array(centroid(h1[u, v], ctr1, 15)) - np.array(centroid(bank0[u, v], (k, k), 15))
        assert np.abs(got - want).max() < 0.1, (u, v, got)


def test_integer_tilt_is_an_exact_translation(bank0, small_cfg):
    """A Noll-2 tilt giving exactly 2 px (c = 2 px·NA·pitch/(2λ)) translates the bank by +2
    columns: H_tilt[..., x] = H[..., x − 2] (periodic simulation grid); to 1e-4 of the max."""
    cfg = small_cfg
    c = 2 * cfg.pixel_pitch * cfg.na / (2 * cfg.wavelength)
    h1 = view_psfs(cfg, _tilt(c, 2), size=45)
    diff = h1[..., 10:35, 12:37] - bank0[..., 10:35, 10:35]
    assert np.abs(diff).max() < 1e-4 * bank0.max()


def _otf_row(h, n=720):
    """|OTF| of one view PSF along the x frequency axis (normalised to DC), n-point FFT."""
    pad = np.zeros((n, n))
    k = h.shape[-1]
    pad[:k, :k] = h
    otf = np.abs(np.fft.rfft2(pad))
    return (otf / otf[0, 0])[0, :n // 2], np.arange(n // 2) / n


def test_view_otf_nulls_sit_at_the_lenslet_aperture_zeros(bank0, small_cfg):
    """In focus, the centre view integrates a point's light uniformly over the lenslet that
    holds it (edges blurred by the main lens's Airy spot), so its OTF is close to the Fourier
    transform of a disk of diameter D = nnum px: nulls at j1,k / (π D) cycles/px (0.1355,
    0.2481 for D = 9). Measured 0.1389, 0.2528 (+2.5 %, +1.9 %; FFT bin 0.0014): tolerance
    4 %; depth 3e-5 of DC (< 1e-3). Views off the axis fill that null (Methods: the small
    coded aperture's diffraction makes the views' PSFs differ, which ISA exploits), more toward
    the pupil edge: 0.004 / 0.012 / 0.059 / 0.095 of DC for views 1-4 off the centre row."""
    from scipy.special import jn_zeros

    n = small_cfg.nnum
    c = n // 2
    otf, f = _otf_row(bank0[c, c])
    minima = [i for i in range(1, f.size - 1) if otf[i] < otf[i - 1] and otf[i] < otf[i + 1]]
    want = jn_zeros(1, 2) / (np.pi * n)
    got = f[minima[:2]]
    assert np.all(np.abs(got / want - 1) < 0.04), (got, want)
    i0 = minima[0]
    assert otf[i0] < 1e-3
    fill = [_otf_row(bank0[c, c + k])[0][i0] for k in range(1, c + 1)]
    assert np.all(np.diff(fill) > 0), fill
    assert fill[0] > 3 * otf[i0] and fill[-1] > 0.05, fill


@pytest.mark.parametrize("depth_over_f", [1.0, -1.0])
def test_defocus_parallax(small_cfg, depth_over_f):
    """Light-field parallax (conventions.md): view (u, v) moves by +depth/f_ml·(u − c, v − c) px
    relative to the centre view. Geometric slope depth/f_ml = ±1 px per view step. Measured:
    disparity of each view of the centre row / column against the centre view by
    cross-correlation (skimage, 1/50 px), least-squares slope over |u − c| <= 3; within 5 %
    and of the right sign. (Windowed centroids are biased by the lenslet cross-talk lobes of
    the f-number-matched system, so the test uses what depth estimation measures.)"""
    from skimage.registration import phase_cross_correlation

    cfg = small_cfg
    h = view_psfs(cfg, depth=depth_over_f * cfg.mla_focal, size=45).astype(np.float64)
    c = cfg.center
    offs = np.arange(-3, 4)

    def disparity(a, b):
        return phase_cross_correlation(a, b, upsample_factor=50, normalization=None)[0]

    dy = [disparity(h[c + o, c], h[c, c])[0] for o in offs]
    dx = [disparity(h[c, c + o], h[c, c])[1] for o in offs]
    for d in (dy, dx):
        slope = np.polyfit(offs, d, 1)[0]
        assert slope == pytest.approx(depth_over_f, rel=0.05)


def test_subsample_normalisation():
    """subsample = 3: the sub-lattice aligned with whole pixels, times 9, is the subsample = 1
    bank (same simulation grid, oversample 3) to 1e-5 of the max; the sums agree within 1 %
    (each fine point carries 1/9 of a pixel's flux). nnum = 5, matched f-numbers."""
    cfg = SystemConfig(nnum=5, mla_pitch=5 * 4.6e-6, mla_focal=5 * 46e-6, scan=5)
    h1 = view_psfs(cfg, size=25)
    h3 = view_psfs(cfg, subsample=3, size=25)
    assert h3.shape == (5, 5, 75, 75)
    assert np.abs(h3[..., 1::3, 1::3] * 9 - h1).max() < 1e-5 * h1.max()
    assert h3.sum() == pytest.approx(h1.sum(), rel=0.01)


def test_phase_callable_and_amplitude_map(bank0, small_cfg):
    """phase = c·Z4 as a callable equals zernike z4 = c (1e-5 of max); an all-ones amplitude
    map equals the default pupil; blanking the map's columns v >= 5 (pupil rho_x < −0.11)
    darkens views v = 6, 7 (< 8 % of their clear energy: what is left is the lenslets'
    diffraction spill, ~5 % at 1.5 px from the edge) and keeps views v <= 3 (> 90 %)."""
    cfg = small_cfg
    z = np.zeros(4)
    z[3] = 0.4
    a = view_psfs(cfg, z, size=45)
    b = view_psfs(cfg, phase=lambda x, y: 0.4 * zernike_basis(x, y, 4)[3], size=45)
    assert np.abs(a - b).max() < 1e-5 * a.max()
    ones = view_psfs(cfg, amplitude=np.ones((9, 9)), size=45)
    assert np.abs(ones - bank0).max() < 1e-6 * bank0.max()
    amap = np.ones((9, 9))
    amap[:, 5:] = 0
    half = view_psfs(cfg, amplitude=amap, size=45).sum(axis=(2, 3))
    e0 = bank0.sum(axis=(2, 3))
    inner = cfg.view_mask()
    assert np.all(half[:, 6:8][inner[:, 6:8]] < 0.08 * e0[:, 6:8][inner[:, 6:8]])
    assert np.all(half[:, :4][inner[:, :4]] > 0.9 * e0[:, :4][inner[:, :4]])


def test_default_size_keeps_energy(small_cfg):
    """Default K: odd, and it keeps >= 99.5 % of the energy of a much larger (81 px) bank,
    whose centre it matches."""
    h = view_psfs(small_cfg, cache=False)
    k = h.shape[-1]
    assert k % 2 == 1 and h.shape[:2] == (9, 9) and k < 81
    big = view_psfs(small_cfg, size=81)
    assert h.sum() >= 0.995 * big.sum()
    c, r = 40, k // 2
    # same PSFs where both exist, to 1e-4 of the max (the grids differ: far-tail truncation)
    np.testing.assert_allclose(h, big[..., c - r:c + r + 1, c - r:c + r + 1], atol=1e-4 * h.max())


def test_cache_hit_and_miss(tmp_path):
    """A second identical call is a cache hit (same array); a different zernike misses;
    cache=False neither reads nor writes."""
    small_cfg = SystemConfig(nnum=3, mla_pitch=3 * 4.6e-6, mla_focal=3 * 46e-6, scan=3)
    stats = psf_cache.stats
    h0, m0 = stats["hits"], stats["misses"]
    a = view_psfs(small_cfg, _tilt(0.1, 5), size=9, cache=tmp_path)
    assert (stats["hits"], stats["misses"]) == (h0, m0 + 1)
    b = view_psfs(small_cfg, _tilt(0.1, 5), size=9, cache=tmp_path)
    assert (stats["hits"], stats["misses"]) == (h0 + 1, m0 + 1)
    np.testing.assert_array_equal(a, b)
    view_psfs(small_cfg, _tilt(0.2, 5), size=9, cache=tmp_path)
    assert stats["misses"] == m0 + 2
    files = list((tmp_path / "psf").glob("*.npy"))
    assert len(files) == 2
    view_psfs(small_cfg, _tilt(0.1, 5), size=9, cache=False)
    assert (stats["hits"], stats["misses"]) == (h0 + 1, m0 + 2)
    view_psfs(small_cfg, _tilt(0.1, 5), size=9, cache=tmp_path,
              phase=lambda x, y: 0.01 * x)  # a phase callable changes the key
    assert stats["misses"] == m0 + 3
    for f in (tmp_path / "psf").glob("*.npy"):
        f.write_bytes(b"corrupt")  # a corrupt entry is a miss, not an error
    c = view_psfs(small_cfg, _tilt(0.1, 5), size=9, cache=tmp_path)
    assert stats["misses"] == m0 + 4
    np.testing.assert_array_equal(a, c)


def test_env_cache_dir(monkeypatch, tmp_path):
    monkeypatch.setenv("METASENSOR_CACHE", str(tmp_path))
    assert psf_cache.cache_dir() == tmp_path


@pytest.mark.parametrize("kwargs, match", [
    ({"size": 44}, "size"),
    ({"subsample": 2}, "subsample"),
    ({"zernike": np.zeros((2, 3))}, "zernike"),
    ({"zernike": [0, np.nan]}, "zernike"),
    ({"depth": np.inf}, "depth"),
    ({"amplitude": np.ones((4, 4))}, "amplitude"),
    ({"subsample": 3, "oversample": 5}, "oversample"),
    ({"device": "cuda:0" if not __import__("torch").cuda.is_available() else "nope"}, "device"),
])
def test_view_psfs_bad_input(small_cfg, kwargs, match):
    with pytest.raises((ValueError, RuntimeError), match=match):
        view_psfs(small_cfg, cache=False, **kwargs)


def test_widefield_bad_input():
    cfg = SystemConfig()
    with pytest.raises(ValueError, match="sampling"):
        widefield_psf(cfg, sampling=-1.0)
    with pytest.raises(ValueError, match="size"):
        widefield_psf(cfg, size=10)


def test_absurd_aberration_is_refused_before_the_work(monkeypatch):
    # 200 waves of defocus: rays reach 3,163 px, the bank would need 15² x 6,325² floats (34 GiB)
    import psutil

    class Mem:
        available = 8 * 2**30

    monkeypatch.setattr(psutil, "virtual_memory", lambda: Mem)
    with pytest.raises(MemoryError, match=r"PSF bank .*6325.*GiB") as info:
        view_psfs(SystemConfig(), zernike=[0, 0, 0, 200], cache=False)
    assert "\n" not in str(info.value)


def test_cache_keeps_under_its_size_cap_evicting_least_recently_used(monkeypatch, tmp_path):
    import os
    import time

    arr = np.zeros(2**18, np.float32)  # 1 MiB (+128 B header)
    monkeypatch.setenv("METASENSOR_CACHE_MAX_GB", str(2.5 / 1024))  # room for two
    for i, key in enumerate("abc"):
        psf_cache.store(key, arr, tmp_path)
        os.utime(tmp_path / "psf" / f"{key}.npy", (time.time() - 100 + i,) * 2)
        if key == "b":
            assert psf_cache.load("a", tmp_path) is not None  # a hit: "a" is now the newest
    names = sorted(f.stem for f in (tmp_path / "psf").glob("*.npy"))
    assert names == ["a", "c"]  # "b", least recently used, went; the new "c" always stays
    big = np.zeros(2**20, np.float32)  # 4 MiB, over the cap alone: kept, the others go
    psf_cache.store("d", big, tmp_path)
    assert sorted(f.stem for f in (tmp_path / "psf").glob("*.npy")) == ["d"]
    monkeypatch.setenv("METASENSOR_CACHE_MAX_GB", "lots")
    with pytest.raises(ValueError, match="METASENSOR_CACHE_MAX_GB"):
        psf_cache.load("a", tmp_path)
    monkeypatch.setenv("METASENSOR_CACHE_MAX_GB", "inf")
    for key in "xyz":
        psf_cache.store(key, big, tmp_path)
    assert len(list((tmp_path / "psf").glob("*.npy"))) == 4


def test_cache_eviction_leaves_files_being_written(monkeypatch, tmp_path):
    # another process's ".key.XXXX.npy" (written, not yet renamed) is not the cache's to evict
    arr = np.zeros(2**18, np.float32)
    monkeypatch.setenv("METASENSOR_CACHE_MAX_GB", str(1.5 / 1024))
    (tmp_path / "psf").mkdir()
    partial = tmp_path / "psf" / ".other.abc123.npy"
    np.save(partial, arr)
    psf_cache.store("a", arr, tmp_path)
    psf_cache.store("b", arr, tmp_path)
    assert partial.exists()
    assert sorted(f.stem for f in (tmp_path / "psf").glob("[!.]*.npy")) == ["b"]
