"""The Python API a new user meets: file readers and writers at the top level, metrics that
cannot swap their images silently, results whose repr shows shapes."""

import numpy as np
import pytest
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

import metasensor as ms


def test_view_and_raw_readers_are_public(tmp_path):
    cfg = ms.SystemConfig(nnum=3, mla_pitch=3 * 4.6e-6, mla_focal=3 * 46e-6, scan=3)
    views = np.random.default_rng(0).random((3, 3, 6, 9)).astype(np.float32)
    ms.write_views(tmp_path / "v.tif", views, cfg)
    np.testing.assert_array_equal(ms.read_views(tmp_path / "v.tif"), views)
    frames = np.arange(4 * 5 * 6, dtype=np.uint16).reshape(4, 5, 6)
    ms.write_raw(tmp_path / "f.tif", frames)
    np.testing.assert_array_equal(ms.read_raw(tmp_path / "f.tif"), frames)
    np.testing.assert_array_equal(ms.read_raw(tmp_path / "f.tif", 1, 3), frames[1:3])
    with ms.open_raw(tmp_path / "f.tif") as raw:
        assert raw.shape == frames.shape
        np.testing.assert_array_equal(raw[2], frames[2])
    for name in ("read_views", "write_views", "read_raw", "open_raw", "write_raw"):
        assert name in dir(ms)


def test_psnr_and_ssim_take_keywords_in_scikit_images_meaning():
    rng = np.random.default_rng(1)
    truth = rng.random((32, 32))
    image = 0.5 * truth + rng.normal(0, 0.05, truth.shape)  # a narrower range than the truth
    rng_t = truth.max() - truth.min()
    assert ms.metrics.psnr(truth=truth, image=image) == pytest.approx(
        peak_signal_noise_ratio(truth, image, data_range=rng_t))
    assert ms.metrics.ssim(image=image, truth=truth) == pytest.approx(
        structural_similarity(truth, image, data_range=rng_t))
    # a positional call could be read either way; it is refused rather than guessed
    for metric in (ms.metrics.psnr, ms.metrics.ssim):
        with pytest.raises(TypeError):
            metric(truth, image)


def test_capture_repr_shows_shapes_not_values():
    cap = ms.simulate(np.ones((30, 30), np.float32), ms.SystemConfig(), snr_db=30, seed=0)
    text = repr(cap)
    assert "frames=ndarray(shape=(25, 30, 30), dtype=uint16)" in text
    assert "views=ndarray(shape=(15, 15, 5, 5), dtype=float32)" in text
    assert "[[" not in text and len(text) < 2000
    assert all(len(line) < 100 for line in text.splitlines())
