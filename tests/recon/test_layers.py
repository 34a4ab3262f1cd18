"""``reconstruct(depth_layers="auto")``: one bank per depth layer inside a block."""

import numpy as np
import pytest

from metasensor.config import SystemConfig
from metasensor.phasespace.operator import make_geometry
from metasensor.recon.api import reconstruct
from metasensor.recon.layers import (
    DepthLayers,
    favour_sharper,
    layer_weights,
    layer_zernikes,
    resolve_depth_layers,
)
from recon_standin import one_torch_thread  # noqa: F401

CFG = SystemConfig()
Z = np.zeros(11)
Z[4] = 0.2  # 0.2 waves of astigmatism: the known wavefront of the synthetic block


@pytest.fixture(scope="module")
def half_card():
    """A 96-px scene: the chart in focus on the left half, a textured card (the camera
    photograph) 1 mm nearer on the right half (disparity 0.483 view px per view step), both
    through ``Z``; 30 dB, seed 0."""
    import metasensor as ms
    from metasensor.simulation.scenes import load_scene, natural_image

    n, h = 96, 48
    scene = load_scene("chart", n).astype(np.float32)
    scene[:, h:] = 0.1 + 0.9 * natural_image("camera", shape=(n, n - h)).astype(np.float32)
    depth = np.zeros((n, n))
    depth[:, h:] = 1e-3
    cap = ms.simulate(scene, CFG, zernike=Z, depth=depth, snr_db=30, seed=0)
    return cap, h - cap.offset


def test_settings_are_validated():
    assert resolve_depth_layers("off") is None
    assert resolve_depth_layers("auto") == DepthLayers()
    with pytest.raises(ValueError, match="depth_layers"):
        resolve_depth_layers("on")
    with pytest.raises(ValueError, match="min_fraction"):
        DepthLayers(min_fraction=0.5)
    with pytest.raises(ValueError, match="median_samples"):
        DepthLayers(median_samples=4)
    with pytest.raises(ValueError, match="seed_vote"):
        DepthLayers(seed_vote=0.5)
    with pytest.raises(ValueError, match="segment_scale"):
        DepthLayers(segment_scale=0)
    with pytest.raises(ValueError, match="min_separation"):
        DepthLayers(min_separation=0.0)
    from metasensor.scenarios.plastic_wrap import PlasticWrapSettings

    assert PlasticWrapSettings().depth_layers == "off"
    with pytest.raises(ValueError, match="depth_layers"):
        PlasticWrapSettings(depth_layers="on")


def test_refuses_what_it_cannot_model():
    views = np.ones((15, 15, 12, 12), np.float32)
    with pytest.raises(ValueError, match="depth_layers"):
        reconstruct(views, CFG, depth_layers="yes")
    with pytest.raises(ValueError, match="solver='hqs'"):
        reconstruct(views, CFG, depth_layers="auto", iterations=2)
    with pytest.raises(ValueError, match="space_variant"):
        reconstruct(views, CFG, zernike=Z, depth_layers="auto", space_variant=True)
    with pytest.raises(ValueError, match="geometric"):
        reconstruct(views, CFG, method="geometric", depth_layers="auto")


def test_layer_defocus_is_the_paraxial_defocus_of_the_disparity():
    # z = δ · d · mla_focal; paraxial Noll 4 of (z/λ)(sqrt(1 − NA²ρ²) − 1): −z NA² / (4√3 λ)
    delta = 0.5
    z = delta * CFG.scan_step_px * CFG.mla_focal
    out = layer_zernikes(CFG, Z, [0.0, delta])
    np.testing.assert_allclose(out[0, :11], Z, atol=1e-12)
    expected = -z * CFG.na**2 / (4 * np.sqrt(3) * CFG.wavelength)
    assert abs(out[1, 3] - expected) < 1e-3 * abs(expected)  # NA 0.05: the rest is ρ⁴ terms
    assert abs(out[1, 10]) < 0.01 * abs(expected)
    np.testing.assert_allclose(np.delete(out[1], [3, 10]), np.delete(out[0], [3, 10]))


def test_weights_are_a_feathered_partition_of_unity():
    geometry = make_geometry((20, 20), 3, 10)
    labels = np.zeros((20, 20), np.uint8)
    labels[:, 10:] = 1
    w = layer_weights(labels, geometry, 3.0)
    assert w.shape == (2, *geometry.domain) and w.dtype == np.float32
    np.testing.assert_allclose(w.sum(0), 1.0, atol=1e-6)
    assert w.min() >= 0
    oy, ox = geometry.offset
    row = w[1, oy + 30]
    assert row[ox + 5] < 1e-3 and row[ox + 55] > 1 - 1e-3  # 10 px (3.3 σ) from the border
    assert abs(row[ox + 30] - 0.5) < 0.1  # the border: sample 10 starts at pixel 30


def test_the_sharper_layer_grows():
    labels = np.zeros((9, 9), np.uint8)
    labels[:, 5:] = 1
    sharp0 = np.array([[0, 0, 0, 0, 0.1], [0, 0, 0, 0.7, 0.1]])  # layer 0 the sharper
    out = favour_sharper(labels, sharp0, 1)
    assert (out[:, :6] == 0).all() and (out[:, 6:] == 1).all()
    out = favour_sharper(labels, sharp0[::-1], 2)  # layer 1 the sharper
    assert (out[:, :3] == 0).all() and (out[:, 3:] == 1).all()


def test_one_layer_is_reconstructed_exactly_as_without_the_model(half_card):
    cap, c = half_card
    chart = np.ascontiguousarray(cap.views[:, :, :, :c // CFG.scan_step_px - 2])  # chart only
    off = reconstruct(chart, CFG, zernike=Z)
    auto = reconstruct(chart, CFG, zernike=Z, depth_layers="auto")
    assert auto.depth_layers == [[()]]
    np.testing.assert_array_equal(auto.image, off.image)


def test_a_layer_the_data_do_not_fit_better_is_refused(half_card, monkeypatch):
    """A block of one depth given a false second layer (the nearer card's 0.483 on half of the
    chart, as the disparity halo along a nearer object's border reads): the two-layer fit
    explains that half's views worse, so the block keeps its one-bank image."""
    import metasensor.recon.layers as layers

    cap, c = half_card
    chart = np.ascontiguousarray(cap.views[:, :, :, :c // CFG.scan_step_px - 2])
    off = reconstruct(chart, CFG, zernike=Z)

    def false_split(window, cfg, zernike, region, settings, device=None, guide=None):
        labels = np.zeros(window.shape[-2:], np.uint8)
        labels[:, labels.shape[1] // 2:] = 1
        return layers.LayerMap(disparity=np.array([0.0, 0.483]), labels=labels,
                               fraction=np.array([0.5, 0.5]))

    monkeypatch.setattr(layers, "find_layers", false_split)
    auto = reconstruct(chart, CFG, zernike=Z, depth_layers="auto")
    assert auto.depth_layers == [[()]]
    np.testing.assert_array_equal(auto.image, off.image)


def test_layers_fit_better_compares_the_layer_defocused_most():
    from metasensor.recon.layers import layers_fit_better

    labels = np.zeros((10, 10), np.uint8)
    labels[:, 5:] = 1
    region = (slice(1, 9), slice(1, 9))
    one = np.ones((10, 10))
    two = np.full((10, 10), 0.8)
    assert layers_fit_better(labels, region, one, two, (0.0, 0.5))
    two[:, 5:] = 1.3  # layer 1 (0.5 from the wavefront) fitted worse: refused
    assert not layers_fit_better(labels, region, one, two, (0.0, 0.5))
    assert layers_fit_better(labels, region, one, two, (0.0, 0.5), ratio=1.4)
    assert layers_fit_better(labels, region, one, two, (-0.3, 0.1))  # layer 0 tested: 0.8
    assert not layers_fit_better(np.zeros((10, 10)), region, one, 0.5 * one, (0.0, 0.5))


def test_two_layers_bring_the_nearer_card_into_focus(half_card):
    from metasensor.scenarios.measure import resolved_frequency

    cap, c = half_card
    t = cap.truth
    n = t.shape[0]
    chart, card = (slice(8, n - 8), slice(8, c - 8)), (slice(8, n - 8), slice(c + 8, n - 8))
    off = reconstruct(cap.views, CFG, zernike=Z).image
    rec = reconstruct(cap.views, CFG, zernike=Z, depth_layers="auto")
    (layers,), = rec.depth_layers
    # the layers relative to the given wavefront: the chart at 0, the card at 0.483
    assert abs(layers[0]) < 0.05 and abs(layers[1] - 0.483) < 0.05
    f_off = [resolved_frequency(off[s], t[s]) for s in (chart, card)]
    f_two = [resolved_frequency(rec.image[s], t[s]) for s in (chart, card)]
    # measured: one bank 0.268 / 0.079 cycles/px (the card 1 mm out of focus; the chart kept
    # by HQS's misfit weights, 0.128 without them), two layers 0.259 / 0.175: the card more
    # than doubles, the chart holds (within 5 %)
    assert f_two[1] > 2 * f_off[1]
    assert f_two[0] >= 0.95 * f_off[0]


def _box_block(n: int = 40):
    """A block on the view grid: a grey card (rows/cols 10-29) on a white chart with dark bars;
    the card's left half textured (its disparity 0.5 read with confidence), its right half flat
    (read as the chart's 0.0, little confidence), a halo of -0.4 one sample outside its border;
    the chart at 0.0 with noise."""
    rng = np.random.default_rng(0)
    guide = np.ones((n, n))
    guide[2:6, 4:36:6] = 0.1  # bars
    guide[34:38, 4:36:6] = 0.1
    card = np.zeros((n, n), bool)
    card[10:30, 10:30] = True
    guide[card] = 0.6
    guide[10:30, 10:20] += 0.15 * rng.standard_normal((20, 10))  # the card's texture
    disp = 0.03 * rng.standard_normal((n, n))
    conf = np.full((n, n), 0.4)
    disp[10:30, 10:20] += 0.5
    conf[10:30, 20:30] = 0.05  # flat: the chart's disparity, guessed
    halo = np.zeros((n, n), bool)
    halo[9:31, 9:31] = True
    halo &= ~card
    disp[halo] = -0.4
    return guide, disp, conf, card


def test_segments_give_a_flat_part_of_the_card_its_layer():
    from skimage.filters import threshold_otsu

    from metasensor.recon.layer_segments import segment_layers

    guide, disp, conf, card = _box_block()
    valid = np.ones(disp.shape, bool)
    use = np.zeros(disp.shape, bool)
    use[3:-3, 3:-3] = True
    thr = float(threshold_otsu(disp[use]))
    per_pixel = disp > thr
    assert (per_pixel & card).sum() <= 0.55 * card.sum()  # the flat half reads the chart
    found = segment_layers(disp, conf, valid, guide, use, thr, DepthLayers())
    lab = found.labels.astype(bool)
    # the card's border is an edge of the image: the whole card, nothing of the chart
    assert (lab & card).sum() >= 0.9 * card.sum()  # measured 0.93 (per pixel: 0.5)
    assert (lab & ~card).sum() <= 0.01 * (~card).sum()
    assert abs(found.disparity[1] - 0.5) < 0.05 and abs(found.disparity[0]) < 0.05


def test_segments_without_a_clear_vote_for_one_layer_give_one_layer():
    from metasensor.recon.layer_segments import segment_layers

    guide, disp, conf, card = _box_block()
    disp[card] = 0.03  # the card reads the chart's disparity everywhere
    use = np.ones(disp.shape, bool)
    assert segment_layers(disp, conf, np.ones(disp.shape, bool), guide, use, 0.25,
                          DepthLayers()) is None
