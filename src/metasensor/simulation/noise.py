"""Detector noise: Poisson photon noise, Gaussian read noise, ADC quantisation (seeded).

Units. Every simulator output is in detector counts (DN). A clean value ``c`` DN corresponds to
``c / gain`` photo-electrons, ``gain = full_scale / photons`` DN per electron, where
``full_scale = 2**bit_depth - 1`` and ``photons`` is the number of photo-electrons that fill the
ADC (the photon budget per pixel at full scale). A noisy value is

    DN = clip(round(gain * (Poisson(c / gain) + Normal(0, read_noise))), 0, full_scale).

A target SNR instead of ``photons``: SNR = 10 log10(Σ clean² / Σ (noisy − clean)²) over all
samples; :func:`gain_for_snr` solves the expected noise power (Poisson + read + quantisation)
for the gain, and :func:`add_noise` refines it on the realised noise (a few steps)
(clipping at 0 and full scale changes the noise of very dark or saturated samples).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["NoiseModel", "gain_for_snr", "measure_snr", "apply_noise", "add_noise"]


@dataclass(frozen=True)
class NoiseModel:
    """gain [DN / e-], read_noise [e- r.m.s.], bit_depth [bits]; ``gain=None``: noise-free
    (values are still rounded to integer DN and clipped to the ADC range)."""

    gain: float | None
    read_noise: float = 2.0
    bit_depth: int = 12

    @property
    def full_scale(self) -> int:
        return 2 ** self.bit_depth - 1

    @property
    def photons(self) -> float | None:
        """Photo-electrons at full scale."""
        return None if self.gain is None else self.full_scale / self.gain


def measure_snr(clean: np.ndarray, noisy: np.ndarray) -> float:
    """10 log10(Σ clean² / Σ (noisy − clean)²) in dB (float64 sums)."""
    a = np.asarray(clean).reshape(-1)
    b = np.asarray(noisy).reshape(-1)
    if a.shape != b.shape:
        raise ValueError(f"clean and noisy differ in size: {a.size} vs {b.size}")
    p_sig = p_err = 0.0
    for s in range(0, a.size, 2**22):
        c = a[s:s + 2**22].astype(np.float64)
        e = b[s:s + 2**22].astype(np.float64) - c
        p_sig, p_err = p_sig + float(c @ c), p_err + float(e @ e)
    if p_err == 0:
        return math.inf
    return 10.0 * math.log10(p_sig / p_err)


def gain_for_snr(sum_c: float, sum_c2: float, n: int, snr_db: float, read_noise: float) -> float:
    """Gain g [DN/e-] giving the expected SNR: Σc²/10^(snr/10) = g Σc + n g² σ² + n/12."""
    if not math.isfinite(snr_db):
        raise ValueError(f"snr_db must be finite, got {snr_db!r}")
    target = sum_c2 / 10.0 ** (snr_db / 10.0) - n / 12.0
    if target <= 0:
        raise ValueError(f"snr_db {snr_db} exceeds what quantisation allows for this scene")
    a = n * read_noise**2
    b = sum_c
    if a == 0:
        return target / b
    return (-b + math.sqrt(b * b + 4.0 * a * target)) / (2.0 * a)


def apply_noise(clean: np.ndarray, model: NoiseModel, rng: np.random.Generator,
                chunk: int = 2**22) -> np.ndarray:
    """Noisy, quantised DN (float32, integer values) of ``clean`` DN; processed in chunks."""
    clean = np.asarray(clean, dtype=np.float32)
    out = np.empty(clean.shape, dtype=np.float32)
    flat_in, flat_out = clean.reshape(-1), out.reshape(-1)
    fs = model.full_scale
    for s in range(0, flat_in.size, chunk):
        c = np.maximum(flat_in[s:s + chunk], 0.0)
        if model.gain is None:
            v = c.copy()
        else:
            v = rng.poisson(c.astype(np.float64) / model.gain).astype(np.float32)
            if model.read_noise > 0:
                v += np.float32(model.read_noise) * rng.standard_normal(c.shape, np.float32)
            v *= np.float32(model.gain)
        np.rint(v, out=v)
        np.clip(v, 0, fs, out=v)
        flat_out[s:s + chunk] = v
    return out


def add_noise(clean: np.ndarray, snr_db: float | None, photons: float | None,
              read_noise: float, bit_depth: int, seed: int | np.random.SeedSequence
              ) -> tuple[np.ndarray, NoiseModel]:
    """Noisy views for a target SNR (dB) or photon budget; returns (noisy, model used)."""
    if snr_db is not None and photons is not None:
        raise ValueError("give either snr_db or photons, not both")
    if read_noise < 0 or not math.isfinite(read_noise):
        raise ValueError(f"read_noise must be >= 0, got {read_noise!r}")
    if photons is not None and not (photons > 0 and math.isfinite(photons)):
        raise ValueError(f"photons must be positive, got {photons!r}")
    fs = 2**bit_depth - 1
    if snr_db is None:
        model = NoiseModel(None if photons is None else fs / photons, read_noise, bit_depth)
        return apply_noise(clean, model, np.random.default_rng(seed)), model
    flat = np.asarray(clean, dtype=np.float32).reshape(-1)
    s1 = s2 = 0.0
    for s in range(0, flat.size, 2**22):
        c = flat[s:s + 2**22].astype(np.float64)
        s1, s2 = s1 + float(c.sum()), s2 + float(c @ c)
    gain = gain_for_snr(s1, s2, flat.size, snr_db, read_noise)
    return _search_gain(clean, snr_db, gain, read_noise, bit_depth, seed)


SNR_TOLERANCE_DB = 0.1  # the search stops within this of the target
SNR_ACCEPT_DB = 0.5  # after SNR_STEPS, a realised SNR within this is still accepted
SNR_STEPS = 30
MAX_GAIN_FACTOR = 1e3  # gain at most this x full scale (a thousandth of a photon at full scale)


def _search_gain(clean, snr_db: float, gain: float, read_noise: float, bit_depth: int, seed
                 ) -> tuple[np.ndarray, NoiseModel]:
    """Gain whose realised SNR (same seed) is ``snr_db``: clipping at 0 and full scale moves the
    SNR away from the expected one (gain_for_snr), so the gain is corrected on the realised
    noise: steps by the Poisson law (noise power ~ gain) until the target is bracketed, then
    regula falsi in log gain. The SNR falls as the gain rises; one still above the target at
    ``MAX_GAIN_FACTOR`` x full scale cannot be reached (one-line ValueError)."""
    max_log = math.log(MAX_GAIN_FACTOR * (2**bit_depth - 1))

    best = None  # the fixed seed makes the SNR jump with the gain: keep the closest realised

    def realise(g):
        nonlocal best
        model = NoiseModel(g, read_noise, bit_depth)
        noisy = apply_noise(clean, model, np.random.default_rng(seed))
        got = measure_snr(clean, noisy)
        if best is None or abs(got - snr_db) < abs(best[2] - snr_db):
            best = (noisy, model, got)
        return noisy, model, got

    noisy, model, got = realise(gain)
    above = below = None  # (log gain, SNR) with SNR above / below the target
    for _ in range(SNR_STEPS):
        if abs(got - snr_db) <= SNR_TOLERANCE_DB:
            return noisy, model
        lg = math.log(model.gain)
        if got > snr_db:
            above = (lg, got)
        else:
            below = (lg, got)
        if above is not None and below is not None:
            (la, sa), (lb, sb) = above, below
            if abs(lb - la) < 1e-9:  # bracket closed on a jump of the realised SNR
                break
            lg = la + (sa - snr_db) * (lb - la) / (sa - sb)
        else:
            lg = lg + (got - snr_db) / 10.0 * math.log(10.0) * (2.0 if below is None else 1.0)
            if below is None and lg >= max_log:
                if above[0] >= max_log:
                    raise ValueError(
                        f"snr_db {snr_db:g} cannot be reached: clipping at 0 and full scale "
                        f"keeps the SNR at {got:.2f} dB even at a thousandth of a photon "
                        "per full scale")
                lg = max_log
        noisy, model, got = realise(math.exp(lg))
    noisy, model, got = best
    if abs(got - snr_db) <= SNR_ACCEPT_DB:
        return noisy, model
    raise ValueError(f"snr_db {snr_db:g} cannot be reached: the closest is {got:.2f} dB "
                     "(quantisation and clipping limit it for this scene)")
