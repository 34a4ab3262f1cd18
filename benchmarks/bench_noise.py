"""The noise model of the data term: one global weight against Poisson–Gaussian weights.

Every capture: the simulator (inverse-crime free, Poisson photon noise + Gaussian read noise +
12-bit quantisation), aberration-free, in focus, 5 x 5 scan, seed 0, at two light levels:

- ``low light``: 625 photo-electrons at full scale (the brightest clean view sample at 80 % of
  it: 500 e-), read noise 3 e- r.m.s.;
- ``30 dB``: the simulator's SNR setting (the gain solved for 30 dB per frame), read noise 2 e-.

Scenes: the camera and astronaut photographs and the bar chart of the demo (``bars``; 256 px
fields, 240 px of truth; quick: the camera at 166 px). Each capture is reconstructed by the
contract call ``ms.reconstruct(views, cfg, method="isa", noise_model=...)`` with

- HQS (the default sparse-gradient solver): ``"global"`` (one weight, today's default), the
  capture's own model (``PoissonGaussian.from_metadata(cap.noise)``: ``metadata``) and the model
  fitted to the views (``"fit"``);
- Richardson–Lucy (5 iterations, 16 subsets): plain, and shifted-Poisson with the capture's model.

Rows: SSIM, PSNR, resolved frequency (global and worst of 3 x 3 regions; ``metrics.spectral``),
the bar chart's finest resolved period per location, wall seconds and the cost ratio to the
same solver's global-weight run on the same capture; and, per capture, the fit's (a, b) against
the metadata's. Cost: wall time on the shared 2-core machine, one thread.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))
sys.path.insert(0, str(HERE))

SIZE_FULL, SIZE_QUICK = 256, 166
SCENES_FULL = ("camera", "astronaut", "bars")
SCENES_QUICK = ("camera",)
LIGHT = {"low light": {"photons": 625.0, "read_noise": 3.0},
         "30 dB": {"snr_db": 30.0, "read_noise": 2.0}}
RL_ITERATIONS = 5


def _runs(true_model):
    """(solver, noise label, reconstruct keywords) of one capture."""
    return [("hqs", "global", {"solver": "hqs", "noise_model": "global"}),
            ("hqs", "metadata", {"solver": "hqs", "noise_model": true_model}),
            ("hqs", "fit", {"solver": "hqs", "noise_model": "fit"}),
            ("rl", "global", {"solver": "rl", "iterations": RL_ITERATIONS,
                              "noise_model": "global"}),
            ("rl", "metadata", {"solver": "rl", "iterations": RL_ITERATIONS,
                                "noise_model": true_model})]


def case(name: str, size: int, light: str) -> list[dict]:
    """Simulate one capture and reconstruct it with each noise model (module docstring)."""
    import metasensor as ms
    from bench_quality import _layout, _scene, scores
    from metasensor.solvers.noise_fit import fit_poisson_gaussian
    from metasensor.solvers.noise_model import PoissonGaussian

    cfg = ms.SystemConfig()
    cap = ms.simulate(_scene(name, size), cfg, seed=0, comparison=False, **LIGHT[light])
    true_model = PoissonGaussian.from_metadata(cap.noise)
    fit = fit_poisson_gaussian(cap.views)
    bars = _layout(name, size, cap)
    key = {"scene": name, "truth_px": cap.truth.shape[0], "light": light,
           "snr_db": round(float(cap.snr_db), 2),
           "photons_brightest": round(float(cap.views_clean.max()) / true_model.a, 1),
           "a_true": true_model.a, "b_true": true_model.b,
           "a_fit": fit.model.a, "b_fit": fit.model.b}
    rows, base = [], {}
    for solver, label, kw in _runs(true_model):
        t0 = time.perf_counter()
        rec = ms.reconstruct(cap.views, cfg, method="isa", **kw)
        seconds = time.perf_counter() - t0
        base.setdefault(solver, seconds)
        rows.append({**key, "solver": solver, "noise": label,
                     **scores(rec.image, cap.truth, bars), "seconds": seconds,
                     "cost_ratio": seconds / base[solver]})
    return rows


def run(quick: bool = False) -> list[dict]:
    import torch

    torch.set_num_threads(1)
    size = SIZE_QUICK if quick else SIZE_FULL
    rows: list[dict] = []
    for light in LIGHT:
        for name in SCENES_QUICK if quick else SCENES_FULL:
            rows += case(name, size, light)
    return rows


if __name__ == "__main__":  # pragma: no cover
    from _usage import exit_on_help

    exit_on_help(__doc__)
    import json

    for r in run(quick="--quick" in sys.argv):
        print(json.dumps(r, default=float))
