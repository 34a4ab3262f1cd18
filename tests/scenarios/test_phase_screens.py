"""Phase screens of the scenarios against theory (structure functions) and their geometry."""

import numpy as np
import pytest

from metasensor.scenarios.screens import (
    LayeredTurbulence,
    PlasticWrap,
    fit_screen,
    gaussian_structure,
    kolmogorov_screen,
    kolmogorov_structure,
    structure_function,
)


def test_kolmogorov_structure_function_within_ten_percent():
    # an ensemble statistic: single screens scatter by 10-20 % (their lowest modes)
    lags = [2, 4, 8, 16]
    screens = np.stack([kolmogorov_screen(1024, 8.0, seed=k) for k in range(4)])
    ratio = structure_function(screens, lags) / kolmogorov_structure(lags, 8.0)
    assert np.all(np.abs(ratio - 1) <= 0.10), ratio


def test_kolmogorov_screen_seeded_and_leaves_global_state():
    state = np.random.get_state()[1].copy()  # noqa: NPY002
    a = kolmogorov_screen(64, 4.0, seed=3, generate=128)
    assert np.array_equal(a, kolmogorov_screen(64, 4.0, seed=3, generate=128))
    assert not np.array_equal(a, kolmogorov_screen(64, 4.0, seed=4, generate=128))
    assert np.array_equal(np.random.get_state()[1], state)  # noqa: NPY002
    with pytest.raises(ValueError, match="r0_px"):
        kolmogorov_screen(64, -1.0)


def test_plastic_wrap_statistics_and_anisoplanatism():
    wrap = PlasticWrap(layers=3, rms_waves=3.0, correlation=0.12, spread=0.6, seed=1)
    sheets = wrap.sheets()
    lags = [1, 2, 4, 8, 16]
    sigma = 3.0 / np.sqrt(3)
    measured = structure_function(sheets, lags)
    theory = gaussian_structure(lags, sigma, 0.12 * wrap.samples)
    assert np.all(np.abs(measured / theory - 1) <= 0.10)
    centre = wrap.wavefront(0, 0)
    assert 2.0 < centre.std() < 4.5  # several waves r.m.s. over the pupil
    # different field points see different parts of the sheets: on average over the field's
    # edge, the wavefront differs from the centre's by more than its own r.m.s. (correlation
    # below 0.5)
    edge = [(1, 1), (1, 0), (1, -1), (0, 1), (0, -1), (-1, 1), (-1, 0), (-1, -1)]
    diff = np.mean([np.std(wrap.wavefront(y, x) - centre) for y, x in edge])
    assert diff > np.mean([np.std(wrap.wavefront(y, x)) for y, x in edge])
    z = wrap.field_zernike()(np.array([0.0, 1.0]), np.array([0.0, 1.0]))
    assert z.shape == (2, 45) and np.all(z[:, :3] == 0)
    assert np.linalg.norm(z[0] - z[1]) > 1.0
    assert np.array_equal(PlasticWrap(seed=1).sheets(), sheets)


def test_layered_turbulence_flows_and_differs_over_field():
    turb = LayeredTurbulence(d_over_r0=5.0, samples=32, seed=2)
    scr = turb.screens(9)
    assert scr.shape == (9, 32, 32) and scr.dtype == np.float32
    assert np.allclose(scr.mean(axis=(1, 2)), 0, atol=1e-5)
    # frozen flow: the screen changes during the scan
    assert np.abs(scr[0] - scr[-1]).std() > 0.05
    fz = turb.field_zernike(9)(np.array([0.0, 1.0]), np.array([0.0, 1.0]))
    assert np.allclose(fz[0], 0, atol=1e-9) and np.linalg.norm(fz[1]) > 0.02
    z = fit_screen(scr[4].astype(float))
    assert z[:3].tolist() == [0, 0, 0] and np.isfinite(z).all()


def test_plastic_wrap_block_variation_grows_with_spread_and_block_size():
    # DAO assumes one aberration per block: the wrap's change from a block's centre to its
    # corners is 0 for a wrap seen alike by every field point, and grows with the footprints'
    # spread over the field and with the block's size
    still = PlasticWrap(correlation=0.25, spread=0.0, samples=32).block_variation((2, 2))
    assert still.shape == (2, 2) and np.allclose(still, 0)
    narrow = PlasticWrap(correlation=0.25, spread=0.15, samples=32).block_variation((2, 2))
    wide = PlasticWrap(correlation=0.25, spread=0.6, samples=32).block_variation((2, 2))
    small = PlasticWrap(correlation=0.25, spread=0.6, samples=32).block_variation((4, 4))
    assert 0 < narrow.mean() < wide.mean()
    assert small.mean() < wide.mean()
    with pytest.raises(ValueError, match="blocks"):
        PlasticWrap().block_variation((0, 2))


def test_plastic_wrap_scenario_wrap_is_uniform_enough_per_dao_block():
    # the scenario's wrap: anisoplanatic over the field (blocks' Noll 4-45 differ by about a
    # wave) yet within 0.25 waves of uniform over each of its 4 x 4 DAO blocks, where DAO's
    # estimates stay within 0.4 waves of the truth (0.6 D of spread: 0.8 waves per block, DAO
    # off by up to 1.1 waves; docs/decisions.md)
    from metasensor.optics.field import block_centres_normalised
    from metasensor.scenarios.plastic_wrap import PlasticWrapSettings

    s = PlasticWrapSettings()
    assert s.blocks == (4, 4)
    assert s.wrap.block_variation(s.blocks).max() < 0.25
    yn, xn = block_centres_normalised(4, 4)
    z = s.wrap.field_zernike()(yn, xn)[..., 3:].reshape(16, -1)
    assert np.sqrt(((z[:, None] - z[None]) ** 2).sum(-1)).max() > 1.0
    assert np.sqrt((z**2).sum(-1)).min() > 0.9  # about a wave or more at every block
