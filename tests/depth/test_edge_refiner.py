"""The learned choice of each depth-edge pixel's layer (metasensor.depth.learned): the shipped
weights, what it may change, its training's reproducibility, its settings' checks. The
full-size figures are bench_depth's."""

import warnings

import numpy as np
import pytest
import torch

import metasensor as ms
from metasensor.depth.edgefeatures import CHANNELS, PATCH, edge_samples
from metasensor.depth.edges import two_layer_pixels
from metasensor.depth.learned import (
    EdgeNet,
    EdgeRefiner,
    load_refiner,
    refine_edges,
    save_refiner,
)
from metasensor.depth.refiner_training import samples, scene_record, train, training_scene
from metasensor.depth.speckle import Speckles, remove_speckles, speckle_mask


@pytest.fixture(scope="module")
def small_scene():
    """A random training-family scene (5 x 5 views, 48 px, 35 dB), the estimator's record."""
    sv = training_scene(nnum=5, size=48, max_disparity=3.0, snr_db=35.0, seed=123)
    return sv, scene_record(sv)


def test_shipped_weights_are_small_float32_and_load_without_pickle():
    from importlib import resources

    src = resources.files("metasensor.depth").joinpath("data", "edge_refiner.npz")
    with resources.as_file(src) as path:
        assert path.stat().st_size <= 1_000_000
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files if not k.startswith("_")}
    assert all(a.dtype == np.float32 for a in arrays.values())
    net = load_refiner()
    assert sum(p.numel() for p in net.parameters()) <= 50_000
    x = torch.zeros((3, CHANNELS, PATCH, PATCH))
    p = net.probability(x)
    assert p.shape == (3,) and bool(((p >= 0) & (p <= 1)).all())


def test_refiner_only_chooses_between_the_two_layers_of_each_edge(small_scene):
    sv, (stack, au, av, disp, conf) = small_scene
    before = disp.clone()
    out = refine_edges(stack, au, av, disp, conf, EdgeRefiner(passes=1, clean=None))
    assert torch.equal(disp, before)  # the input is not modified
    edge, lo, hi, _ = two_layer_pixels(disp, 1.5, float(np.abs(au).max()))
    changed = out != disp
    assert bool((changed <= edge).all())  # only two-layer edge pixels change
    assert bool(changed.any())
    gap = (hi - lo)[changed]
    new = out[changed]
    # the new value is one of the two layers (the mean of the neighbours on it)
    near = torch.minimum((new - lo[changed]).abs(), (new - hi[changed]).abs())
    assert bool((near <= 0.25 * gap + 1e-6).all())
    # a second round changes pixels next to the first round's edges only
    twice = refine_edges(stack, au, av, disp, conf, EdgeRefiner(passes=2, clean=None))
    grown = torch.nn.functional.max_pool2d(edge.float()[None, None], 3, 1, 1)[0, 0] > 0
    assert bool(((twice != disp) <= grown).all())
    # probability 1 - eps changes (almost) nothing
    sure = refine_edges(stack, au, av, disp, conf,
                        EdgeRefiner(probability=0.999999, clean=None))
    assert int((sure != disp).sum()) <= int(changed.sum())


def test_refiner_lowers_the_error_on_a_hard_scene():
    """Mixed scene (9 x 9 views, 40 dB, 64 px, never in training): MSE x 100 lower with the
    refiner than with the coverage re-decision alone, BadPix(0.07) not higher."""
    sv = ms.depth.scenes.benchmark_scene("mixed", nnum=9, size=64, max_disparity=3.0,
                                         snr_db=40.0, seed=1)
    record = scene_record(sv)
    m = np.zeros(sv.disparity.shape, bool)
    m[15:-15, 15:-15] = True
    got = []
    for disp in (record[3], refine_edges(*record, EdgeRefiner())):
        err = disp.numpy()[m] - sv.disparity[m]
        got.append((np.mean(err**2), np.mean(np.abs(err) > 0.07)))
    (mse0, bad0), (mse, bad) = got
    assert mse < 0.8 * mse0 and bad <= bad0, got


def test_weak_speckles_are_removed_before_the_choice():
    """Occluders (5 x 5 views, 30 dB, 64 px, never in training): the choice on the map without
    its weak speckles, which lowers the error."""
    sv = ms.depth.scenes.benchmark_scene("occluders", nnum=5, size=64, max_disparity=3.0,
                                         snr_db=30.0, seed=1)
    stack, au, av, disp, conf = scene_record(sv)
    clean = Speckles(confidence=0.2)
    assert EdgeRefiner().clean == clean
    weak = speckle_mask(disp, 2.0, clean) & (conf < 0.2)
    assert int(weak.sum()) >= 5
    got = refine_edges(stack, au, av, disp, conf, EdgeRefiner())
    cleaned = remove_speckles(disp, 2.0, clean, conf)
    assert torch.equal(got, refine_edges(stack, au, av, cleaned, conf, EdgeRefiner(clean=None)))
    m = np.zeros(sv.disparity.shape, bool)
    m[15:-15, 15:-15] = True
    mse = [np.mean((d.numpy()[m] - sv.disparity[m]) ** 2)
           for d in (refine_edges(stack, au, av, disp, conf, EdgeRefiner(clean=None)), got)]
    assert mse[1] < 0.85 * mse[0], mse


def test_estimate_depth_applies_the_refiner_last(small_scene):
    sv, record = small_scene
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = ms.estimate_depth(sv.views, sv.config, view_mask=np.ones((5, 5), bool),
                                refiner=EdgeRefiner(), speckles=None)
    expected = refine_edges(*record, EdgeRefiner()).numpy()
    # equal up to the float rounding that the thread count changes (1e-7 with two threads)
    np.testing.assert_allclose(res.disparity, expected, rtol=0, atol=1e-5)
    assert np.abs(res.disparity - record[3].numpy()).max() > 0.5  # it moved edge pixels


def test_training_is_reproducible(small_scene, tmp_path):
    sv, record = small_scene
    feats, labels, weights = samples(record, sv.disparity)
    assert feats.shape[1:] == (CHANNELS, PATCH, PATCH) and len(labels) == len(weights) > 20
    runs = [train(feats, labels, weights, steps=15, batch=64, seed=s, log=None)
            for s in (3, 3, 4)]
    a, b, c = (r.state_dict() for r in runs)
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not all(torch.equal(a[k], c[k]) for k in a)
    assert not torch.are_deterministic_algorithms_enabled()  # the caller's setting is back
    # saved and loaded: the same network
    save_refiner(runs[0], tmp_path / "w.npz")
    again = load_refiner(tmp_path / "w.npz")
    x = torch.from_numpy(feats[:8].astype(np.float32))
    assert torch.equal(runs[0].probability(x), again.probability(x))


def test_edge_samples_none_without_edges():
    views = torch.rand((9, 20, 20))
    au, av = np.divmod(np.arange(9), 3)
    flat = torch.zeros((20, 20))
    assert edge_samples(views, au - 1, av - 1, flat, torch.ones((20, 20))) is None
    out = refine_edges(views, au - 1, av - 1, flat, torch.ones((20, 20)))
    assert torch.equal(out, flat)


@pytest.mark.parametrize("kwargs", [dict(probability=0.4), dict(probability=1.0),
                                    dict(jump=0), dict(jump=float("inf")), dict(passes=0),
                                    dict(passes=1.5)])
def test_refiner_settings_are_checked(kwargs):
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        EdgeRefiner(**kwargs)


def test_refiner_clean_type_is_checked():
    with pytest.raises(TypeError, match="clean"):
        EdgeRefiner(clean=4)


def test_estimate_depth_checks_the_refiner_type():
    views = np.random.default_rng(0).random((5, 5, 16, 16)).astype(np.float32)
    with pytest.raises(TypeError, match="refiner"):
        ms.estimate_depth(views, ms.SystemConfig(nnum=5, scan=1), refiner="learned")


def test_network_is_small():
    assert sum(p.numel() for p in EdgeNet().parameters()) <= 50_000


def test_refiner_leaves_scanned_views_alone():
    """Trained on plain light-field views (scan 1): the meta-imaging sensor's scanned views
    (scan 5) get the same map with and without it."""
    from metasensor.depth import synthetic

    cfg = ms.SystemConfig(scan=5)
    tex, layers = synthetic.scene_planes((96, 96), near=-1.5, far=1.0, seed=1)
    sv = synthetic.render_views(tex, layers, cfg, snr_db=30, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plain = ms.estimate_depth(sv.views, cfg, refiner=None)
        learned = ms.estimate_depth(sv.views, cfg, refiner=EdgeRefiner())
    assert np.array_equal(plain.disparity, learned.disparity)


def test_photo_training_scenes_use_no_evaluation_photograph():
    """The training family's photographs (refiner_training.photo_scene) are bundled ones that
    scenes.natural_scene, the evaluation family, never uses; a scene is a function of its seed."""
    from metasensor.depth.refiner_training import (
        TRAINED_ON,
        TRAINING_PHOTOS,
        photo_scene,
        training_specs,
    )
    from metasensor.depth.scenes import PHOTOS

    assert TRAINING_PHOTOS and not set(TRAINING_PHOTOS) & set(PHOTOS)
    assert TRAINED_ON == {}  # the refiner is trained on the estimator's defaults' output
    a = photo_scene(nnum=5, size=40, max_disparity=3.0, snr_db=30.0, seed=7)
    b = photo_scene(nnum=5, size=40, max_disparity=3.0, snr_db=30.0, seed=7)
    assert np.array_equal(a.views, b.views) and np.array_equal(a.disparity, b.disparity)
    assert np.abs(a.disparity).max() <= 3.0 + 1e-6
    assert np.ptp(a.disparity) > 1.0  # objects in front of the background
    sources = [s[0] for s in training_specs(6)]
    assert sorted(set(sources)) == ["occluders", "photo", "random", "thin"]


def test_held_out_seeds_are_not_in_the_training_set():
    """The benchmark's extra hard-scene seeds: no benchmark kind is trained at them (the
    shipped weights' specs hold the 9 x 9 occluders scene of seed 4, so it is skipped)."""
    from metasensor.depth.refiner_training import (
        TRAINING_KINDS,
        TRAINING_SCENES,
        held_out_seeds,
        training_specs,
    )

    seeds = held_out_seeds(3)
    used = {s[4] for s in training_specs(TRAINING_SCENES) if s[0] in TRAINING_KINDS}
    assert seeds == (2, 3, 5) and not set(seeds) & used and 4 in used


def test_refining_on_another_device_leaves_the_cached_network_where_it_was():
    net = load_refiner()
    meta = load_refiner(device="meta")
    assert meta is not net and meta is load_refiner(device="meta")
    assert next(net.parameters()).device.type == "cpu"
    assert next(meta.parameters()).device.type == "meta"
