"""Per-view energies of the prototype's in-focus PSF bank against the authors' (psf_init.mat).

Metric: the energy of each view (sum of its PSF) relative to the centre view, along the central
row from the edge view (offset 7) inwards, compared with the authors' 1.304, 1.070, 1.028,
1.015, 1.009, 1.004, 1.001 (largest relative difference, and the edge view's alone), and the
range over the views at radius 5.5-6.5 (the authors': about 1.07-1.12). Candidates: the pupil
law (uniform, or aplanatic at the object-side NA ``na * magnification``) times the pupil fill
(the pupil image's diameter over the lenslet pitch, ``2 na mla_focal / mla_pitch``), set by the
lenslet focal length at the main lens's f/10 or by the main lens's NA. ``quick``: the prototype,
the aplanatic law alone, and the best match. Accuracy only (no timing); cache off.
"""

from __future__ import annotations

AUTHORS_ROW = (1.304, 1.070, 1.028, 1.015, 1.009, 1.004, 1.001)  # offsets 7 .. 1

# (case, SystemConfig keyword arguments)
CASES = [
    ("prototype (uniform, fill 1)", {}),
    ("aplanatic, fill 1", {"apodization": "aplanatic"}),
    ("uniform, fill 31/30 (f_ml 713 um)", {"mla_focal": 713e-6}),
    ("uniform, fill 16/15 (f_ml 736 um)", {"mla_focal": 736e-6}),
    ("aplanatic, fill 1.02 (f_ml 703.8 um)", {"mla_focal": 703.8e-6, "apodization": "aplanatic"}),
    ("aplanatic, fill 31/30 (f_ml 713 um)", {"mla_focal": 713e-6, "apodization": "aplanatic"}),
    ("aplanatic, fill 31/30 (NA 0.05167)", {"na": 0.05 * 31 / 30, "apodization": "aplanatic"}),
    ("aplanatic, fill 16/15 (f_ml 736 um)", {"mla_focal": 736e-6, "apodization": "aplanatic"}),
]
QUICK = (0, 1, 5)


def _row(name: str, kwargs: dict) -> dict:
    import numpy as np

    from metasensor.config import SystemConfig
    from metasensor.optics.psf import view_psfs

    cfg = SystemConfig(**kwargs)
    e = view_psfs(cfg, cache=False).sum(axis=(2, 3)).astype(np.float64)
    c = cfg.center
    e = e / e[c, c]
    row = e[c, c + 7:c:-1]  # offsets 7 .. 1 towards +x; the bank is symmetric
    err = row / np.asarray(AUTHORS_ROW) - 1.0
    r = np.hypot(*np.mgrid[-c:c + 1, -c:c + 1])
    ring = e[(r > 5.5) & (r <= 6.5)]
    out = {"case": name, "f_ml_um": cfg.mla_focal * 1e6, "na": cfg.na,
           "na_object": cfg.na * cfg.magnification if cfg.apodization == "aplanatic" else 0.0,
           "pupil_fill": cfg.pupil_fill}
    out.update({f"e{k}": float(v) for k, v in zip(range(7, 0, -1), row, strict=True)})
    out.update(edge_err_pct=100 * float(err[0]), row_max_err_pct=100 * float(np.abs(err).max()),
               inner_max_err_pct=100 * float(np.abs(err[1:]).max()),
               ring_min=float(ring.min()), ring_max=float(ring.max()))
    return out


def run(quick: bool = False) -> list[dict]:
    import torch

    torch.set_num_threads(min(2, torch.get_num_threads()))
    cases = [CASES[i] for i in QUICK] if quick else CASES
    return [_row(name, kwargs) for name, kwargs in cases]


if __name__ == "__main__":
    from _usage import exit_on_help

    exit_on_help(__doc__)
    import json

    print(json.dumps(run(quick=True), indent=1))
