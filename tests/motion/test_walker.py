"""The walking-figure scene (articulated motion, occlusion, blur, brightness change) and the
scan-lattice measure on it."""

import numpy as np
import pytest

from metasensor.motion.correct import correct_motion
from metasensor.motion.synthetic import lattice_ratio, natural_scene, scan_artifact
from metasensor.simulation.walker import WalkerOptions, walker_view

ORDER = [(r, c) for r in range(5) for c in range(5)]


@pytest.fixture(scope="module")
def capture():
    return walker_view((180, 180), ORDER, 12, WalkerOptions(height=120.0, seed=1))


def test_walker_scene_moves_only_the_figure(capture):
    v, s, t, mv = capture.view, capture.static, capture.truth, capture.moving
    assert v.shape == s.shape == t.shape == mv.shape == (180, 180) and v.dtype == np.float32
    assert 0.05 < mv.mean() < 0.5
    # outside the moving region the scan sees a static scene: view == static capture
    np.testing.assert_allclose(v[~mv], s[~mv], atol=1e-6)
    assert np.abs(v[mv] - s[mv]).mean() > 0.02
    # the scan artefact (lattice-frequency energy of the error against the truth) shows on the
    # moving region of the view, far less on the static capture's (motion blur only)
    ys, xs = np.nonzero(mv)
    box = (slice(ys.min(), ys.max() + 1), slice(xs.min(), xs.max() + 1))
    assert scan_artifact(v, 5, box, truth=t) > 3 * scan_artifact(s, 5, box, truth=t)


def test_lattice_ratio_is_about_one_without_an_artefact():
    img = natural_scene((160, 160), 1, 1.0, seed=0)
    assert 0.3 < lattice_ratio(img, 5) < 2.0
    striped = img.copy()
    striped[::5] += 0.05  # a row of every lenslet from another time
    assert lattice_ratio(striped, 5) > 5 * lattice_ratio(img, 5)
    with pytest.raises(ValueError, match="mask is empty"):
        lattice_ratio(img, 5, np.zeros(img.shape, bool))


def test_correction_keeps_the_static_scene_and_with_evidence_too(capture):
    """Static regions stay as they are (correlation >= 0.99), with and without the per-sample
    evidence gating."""
    from scipy import ndimage

    still = ~ndimage.binary_dilation(capture.moving, iterations=6)
    for evidence in (False, True):
        out = correct_motion(capture.view, ORDER, 12, evidence=evidence)
        assert np.corrcoef(out[still], capture.view[still])[0, 1] >= 0.99


def test_walker_options_are_validated():
    with pytest.raises(ValueError, match="exposure"):
        WalkerOptions(exposure=2.0)
    with pytest.raises(ValueError, match="too small"):
        walker_view((60, 60), ORDER)
