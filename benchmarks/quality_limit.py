"""Is the aberration-free gap to the 2D sensor physics or solver? The linear-MMSE limit.

For a capture of a photograph (simulator, 5 x 5 scan, SNR 30 dB per frame, seed 0, 256-px field,
240 px of truth) this computes, from the operators' spectra and the capture's own noise, what the
best *linear* reconstruction can resolve, for the meta-imaging sensor and for the 2D sensor:

- Model: a circular domain of the truth's size; the image a stationary Gaussian field whose power
  per DFT coefficient ``P(f)`` is the truth's own radially averaged power spectrum (Hann
  windowed, rescaled by the window's mean square); the views ``y_v = S_d(H_v ⊛ x) + n`` with
  white noise of the capture's measured variance ``σ_v² = mean((views − views_clean)²)`` over
  the 113 used views; the 2D sensor ``y = h ⊛ x + n`` with ``σ_2D² = mean((sensor2d −
  sensor2d_clean)²)`` (Poisson + read noise, approximated as white at its mean variance).
- Per view frequency the d² = 9 aliases are coupled by ``G = Σ_v h_vᴴ h_v``
  (:class:`metasensor.phasespace.normal.FoldedNormal`); the posterior (Wiener / linear-MMSE)
  error covariance is ``C = (G / (N σ_v²) + diag(1/P))⁻¹`` (N pixels); for the 2D sensor
  ``1 / (|H_2D|² / (N σ_2D²) + 1/P)``. The expected error-to-truth power ratio per radial bin,
  ``Σ C_ii / Σ P_i``, is the ratio of ``metasensor.metrics.spectral`` for the best linear
  estimate; its 0.5 crossing the *Wiener-resolved frequency*.
- Check: the Wiener filter applied to one noisy realisation of the model with the photograph
  itself as ``x`` (circular, unwindowed spectral fidelity), to confirm the analytic figure.

Hand-written (no library computes a multi-view aliased Wiener bound). A linear estimator with the
right spectrum is the best of all estimators for Gaussian images only: a non-linear prior can do
better on edges (and did, on the charts); texture is close to Gaussian, where it cannot.
Rows: in focus and 0.25 λ (Noll Z4) off the conjugate plane. Run:
``python benchmarks/bench_quality.py --limit`` (writes ``results/quality_limit.json``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
LIMIT_JSON = HERE / "results" / "quality_limit.json"
PHOTOS = ("camera", "astronaut", "coffee", "chelsea", "rocket", "grass")
OFFSETS = (0.0, 0.25)
SNR_GAINS = (10.0, 20.0)  # dB above the capture's noise: what more light would resolve


def _radial(h: int, w: int, bins: int):
    """Bin index per DFT coefficient (the bins of ``metrics.spectral``), -1 for DC."""
    fy, fx = np.fft.fftfreq(h), np.fft.fftfreq(w)
    rad = np.hypot(fy[:, None], fx[None, :])
    edges = np.linspace(0.0, 0.5, bins + 1)
    idx = np.digitize(rad, edges) - 1
    idx[(idx >= bins) | (rad == 0)] = -1
    return idx, 0.5 * (edges[:-1] + edges[1:])


def _bin_mean(values: np.ndarray, idx: np.ndarray, bins: int) -> np.ndarray:
    keep = idx >= 0
    s = np.bincount(idx[keep], values[keep], minlength=bins)[:bins]
    n = np.bincount(idx[keep], minlength=bins)[:bins]
    return s / np.maximum(n, 1)


def prior_power(truth: np.ndarray, idx: np.ndarray, bins: int) -> np.ndarray:
    """E|X(f)|² per DFT coefficient: the truth's Hann-windowed radial power spectrum."""
    h, w = truth.shape
    win = np.outer(np.hanning(h), np.hanning(w))
    spec = np.abs(np.fft.fft2(win * (truth - truth.mean()))) ** 2 / np.mean(win**2)
    per_bin = np.maximum(_bin_mean(spec, idx, bins), 1e-30)
    return np.where(idx >= 0, per_bin[np.maximum(idx, 0)], 1e30)  # DC: known (the mean)


def _crossing(freq, ratio, threshold=0.5) -> float:
    from metasensor.metrics.spectral import _crossing as crossing

    return crossing(freq, ratio, threshold)


def wiener_meta(cap, bank: np.ndarray, prior: np.ndarray, idx, bins, freq) -> dict:
    """Expected linear-MMSE error ratio of the views (analytic) and of one realisation."""
    from metasensor.metrics.spectral import spectral_fidelity
    from metasensor.phasespace.normal import FoldedNormal
    from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry

    cfg = cap.config
    mask = cfg.view_mask()
    d = cfg.scan_step_px
    h, w = cap.truth.shape
    g = make_geometry((h // d, w // d), d, bank.shape[-1] // 2, pad=False)
    op = PhaseSpaceOperator(bank[mask], g, device="cpu")
    nm = FoldedNormal(op)
    sigma2 = float(np.mean((cap.views[mask] - cap.views_clean[mask]) ** 2))
    n = h * w
    p = nm.fold(torch.from_numpy(prior)).to(torch.complex128)  # (My, Mx, d²)

    def expected(noise_var):
        prec = nm.matrix.to(torch.complex128) / (n * noise_var) + torch.diag_embed(1.0 / p)
        cov = torch.linalg.inv(prec)
        cii = nm.unfold(cov.diagonal(dim1=-2, dim2=-1).real.contiguous()).numpy()
        return _bin_mean(cii, idx, bins) / _bin_mean(prior, idx, bins)

    ratio = expected(sigma2)
    more = {g: _crossing(freq, expected(sigma2 * 10 ** (-g / 10))) for g in SNR_GAINS}
    # one realisation: y = A truth + white noise, x̂ = (G + N σ² diag(1/P))⁻¹ Aᵀy
    x = torch.from_numpy(cap.truth.astype(np.float32))
    gen = torch.Generator().manual_seed(0)
    y = op.forward(x)
    y = y + float(np.sqrt(sigma2)) * torch.randn(y.shape, generator=gen)
    rhs = nm.fold(torch.fft.fft2(op.adjoint(y).to(torch.float64)))
    a = nm.matrix.to(torch.complex128) + torch.diag_embed((n * sigma2) / p)
    xf = torch.linalg.solve(a, rhs.unsqueeze(-1)).squeeze(-1)
    est = torch.fft.ifft2(nm.unfold(xf)).real.numpy()
    real = spectral_fidelity(est, cap.truth, window=False)
    return {"sigma2": sigma2, "ratio": ratio, "resolved": _crossing(freq, ratio),
            "realised_resolved": real.resolved, "realised_ratio": real.ratio, "more": more}


def wiener_2d(cap, prior: np.ndarray, idx, bins, freq) -> dict:
    """Expected linear-MMSE error ratio of the 2D sensor (same lens, in focus)."""
    from metasensor.optics.widefield import widefield_psf

    h, w = cap.truth.shape
    psf = widefield_psf(cap.config)
    k = psf.shape[0]
    pad = np.zeros((h, w))
    pad[:k, :k] = psf
    hf = np.fft.fft2(np.roll(pad, (-(k // 2), -(k // 2)), (0, 1)))
    sigma2 = float(np.mean((cap.sensor2d - cap.sensor2d_clean) ** 2))

    def expected(noise_var):
        var = 1.0 / (np.abs(hf) ** 2 / (h * w * noise_var) + 1.0 / prior)
        return _bin_mean(var, idx, bins) / _bin_mean(prior, idx, bins)

    ratio = expected(sigma2)
    more = {g: _crossing(freq, expected(sigma2 * 10 ** (-g / 10))) for g in SNR_GAINS}
    return {"sigma2": sigma2, "ratio": ratio, "resolved": _crossing(freq, ratio), "more": more}


def limit_case(name: str, offset: float, size: int = 256) -> dict:
    """One photograph at one focus offset: the Wiener-resolved frequencies and ratios."""
    import metasensor as ms

    bq = _bench_quality()
    cfg = ms.SystemConfig()
    cap = ms.simulate(bq._scene(name, size), cfg, snr_db=30.0, seed=0, focus_offset=offset)
    bank = np.asarray(ms.view_psfs(cfg, zernike=cap.zernike), np.float32)
    h, w = cap.truth.shape
    bins = int(np.clip(min(h, w) // 4, 8, 64))
    idx, freq = _radial(h, w, bins)
    prior = prior_power(cap.truth.astype(np.float64), idx, bins)
    meta = wiener_meta(cap, bank, prior, idx, bins, freq)
    two = wiener_2d(cap, prior, idx, bins, freq)
    pick = [int(np.argmin(np.abs(freq - f))) for f in (0.1, 0.2, 0.3)]
    return {"study": "wiener-limit", "scene": name, "focus_offset_waves": offset,
            "truth_px": h, "views_noise_var": meta["sigma2"], "sensor2d_noise_var": two["sigma2"],
            "wiener_resolved_meta": meta["resolved"], "wiener_resolved_2d": two["resolved"],
            "ratio_of_resolved": meta["resolved"] / max(two["resolved"], 1e-9),
            "realised_resolved_meta": meta["realised_resolved"],
            **{f"wiener_resolved_meta_+{g:g}dB": meta["more"][g] for g in SNR_GAINS},
            **{f"wiener_resolved_2d_+{g:g}dB": two["more"][g] for g in SNR_GAINS},
            **{f"meta_ratio_at_{freq[i]:.3f}": float(meta["ratio"][i]) for i in pick},
            **{f"2d_ratio_at_{freq[i]:.3f}": float(two["ratio"][i]) for i in pick},
            "frequency": freq.tolist(), "meta_ratio": meta["ratio"].tolist(),
            "sensor2d_ratio": two["ratio"].tolist()}


def _bench_quality():
    import importlib.util

    spec = importlib.util.spec_from_file_location("bench_quality", HERE / "bench_quality.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def run() -> list[dict]:
    """Every photograph in focus and 0.25 λ off; writes :data:`LIMIT_JSON`."""
    from metasensor.io.atomic import atomic_write_text

    torch.set_num_threads(1)
    rows = []
    for name in PHOTOS:
        for off in OFFSETS:
            rows.append(limit_case(name, off))
            short = {k: v for k, v in rows[-1].items() if not isinstance(v, list)}
            print(json.dumps(short, default=float), flush=True)
            atomic_write_text(LIMIT_JSON, json.dumps({"benchmark": "quality (Wiener limit)",
                                                      "rows": rows}, indent=2, default=float))
    return rows
