"""DAO's Noll modes (dao/modes.py): chosen from the views used where not given, refused where
given modes cannot be determined, and the reconstruction's views reaching DAO."""

import warnings

import numpy as np
import pytest

import metasensor as ms
from metasensor.dao.estimate import dao_modes, dao_unavailable, run_dao
from metasensor.dao.modes import MAX_CONDITION, choose_modes, fit_condition
from metasensor.dao.options import DaoOptions
from metasensor.dao.wavefront import DAO_MODES
from metasensor.recon.dao_choice import block_dao_options
from metasensor.simulation.scenes import load_scene

PROTO = ms.SystemConfig()
SMALL = ms.SystemConfig(nnum=9, scan=3)  # 37 default views: modes 4-45 are rank-deficient


def _z():
    z = np.zeros(45)
    z[3], z[4] = 0.3, 0.2
    return z


@pytest.mark.parametrize("radius", [None, PROTO.pupil_radius_px])
def test_the_prototype_keeps_modes_4_to_45_without_a_warning(radius):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert dao_modes(PROTO, PROTO.view_mask(radius)) == DAO_MODES
    assert fit_condition(PROTO, PROTO.view_mask(radius), DAO_MODES) <= MAX_CONDITION
    assert DaoOptions().modes is None


@pytest.mark.parametrize(("cfg", "last"), [(SMALL, 36), (ms.SystemConfig(nnum=7, scan=7), 21),
                                           (ms.SystemConfig(nnum=5, scan=5), 21)])
def test_few_views_get_the_largest_well_conditioned_leading_set_and_one_warning(cfg, last):
    with pytest.warns(UserWarning, match=f"DAO fits Noll modes 4-{last}, not 4-45") as rec:
        modes = choose_modes(cfg, cfg.view_mask())
    assert modes == tuple(range(4, last + 1)) and len(rec) == 1
    assert fit_condition(cfg, cfg.view_mask(), modes) <= MAX_CONDITION
    assert dao_unavailable(cfg) is None


def test_given_modes_the_views_cannot_determine_are_refused_naming_the_option():
    with pytest.raises(ValueError, match=r"DaoOptions\(modes=\.\.\.\).*4-45.*rank-deficient"
                       r".*range\(4, 37\)") as err:
        choose_modes(SMALL, SMALL.view_mask(), DAO_MODES)
    assert "\n" not in str(err.value)
    assert choose_modes(SMALL, SMALL.view_mask(), range(4, 16)) == tuple(range(4, 16))
    with pytest.raises(ValueError, match="modes must be Noll indices"):
        DaoOptions(modes=())


def test_run_dao_on_few_views_estimates_the_low_orders():
    cap = ms.simulate(load_scene("chart", 90), SMALL, zernike=_z(), snr_db=30, seed=0,
                      comparison=False)
    with pytest.warns(UserWarning, match="modes 4-36"):
        res = run_dao(cap.views, SMALL, max_iter=3)
    assert res.modes == tuple(range(4, 37))
    assert np.sqrt(np.sum((res.zernike[3:45] - _z()[3:45]) ** 2)) < 0.06  # 4-45: ~0.2
    with pytest.raises(ValueError, match="rank-deficient"):
        run_dao(cap.views, SMALL, modes=DAO_MODES, max_iter=1)


def test_the_reconstructions_view_radius_reaches_dao():
    cfg = ms.SystemConfig(nnum=5, scan=5)  # views within radius 1: 5; inside the pupil: 21
    reason = dao_unavailable(cfg, cfg.view_mask(1.0))
    assert "only 5 usable views within view_radius 1.00" in reason
    assert "larger view_radius" in reason and "21 views" in reason
    assert dao_unavailable(cfg, cfg.view_mask(cfg.pupil_radius_px)) is None
    with pytest.warns(UserWarning, match="modes 4-36"):
        dao = block_dao_options("wave", cfg, None, cfg.view_mask(cfg.pupil_radius_px))
    assert dao.method == "wave" and dao.modes == tuple(range(4, 37))
    cap = ms.simulate(load_scene("chart", 60), cfg, zernike=_z(), snr_db=30, seed=0,
                      comparison=False)
    with pytest.warns(UserWarning, match="modes 4-36"):
        rec = ms.reconstruct(cap.views, cfg, method="wave", view_radius=cfg.pupil_radius_px,
                             dao=DaoOptions(max_iter=1), iterations=2)
    assert rec.views_used == 21 and np.any(rec.dao_zernike)
    with pytest.raises(ValueError, match="only 5 usable views"):
        ms.reconstruct(cap.views, cfg, method="wave", view_radius=1.0)
