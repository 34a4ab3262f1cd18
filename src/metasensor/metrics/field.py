"""MTF across the field of view from a chart of slanted squares (centre vs edge, Fig. 2f).

:func:`find_edge_rois` locates slanted-edge squares (dark on bright or bright on dark, rotated a
few degrees; other chart elements such as bar groups or a Siemens star are skipped) by an Otsu
threshold and connected components (scikit-image), and places one ROI on the middle of each of
their four sides, clear of the corners and of other objects. :func:`field_mtf` measures the
slanted-edge MTF in every ROI (:mod:`metasensor.metrics.mtf`) and reports MTF50 against the
normalised field radius (0 at the image centre, 1 at a corner).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from metasensor.metrics.mtf import EdgeMTF, check_roi, measure_edge

__all__ = ["find_edge_rois", "field_mtf", "FieldMTF", "field_radius"]

CENTRE_RADIUS = 1.0 / 3.0  # normalised field radius up to which an ROI counts as "centre"
EDGE_RADIUS = 2.0 / 3.0  # ... and from which it counts as "edge"
GROUP_SPAN = 0.1  # if no ROI is that central (or peripheral): those within this of the extreme


def field_radius(y: float, x: float, shape: tuple[int, int]) -> float:
    """Distance of pixel (y, x) from the image centre over the half-diagonal (0 .. 1)."""
    cy, cx = (shape[0] - 1) / 2, (shape[1] - 1) / 2
    return float(math.hypot(y - cy, x - cx) / math.hypot(shape[0] / 2, shape[1] / 2))


def _square_candidates(mask: np.ndarray, min_side: int, max_side: int):
    """Connected components that look like rotated squares: (label, bbox, side, alpha) for whole
    squares, and (label, bbox, touched borders) for squares cut by one image border."""
    from skimage.measure import label, regionprops

    lab = label(mask, connectivity=1)
    h, w = mask.shape
    out, cut = [], []
    for reg in regionprops(lab):
        r0, c0, r1, c1 = reg.bbox
        bh, bw = r1 - r0, c1 - c0
        if reg.solidity < 0.95:
            continue
        touched = [n for n, t in (("top", r0 == 0), ("bottom", r1 == h), ("left", c0 == 0),
                                  ("right", c1 == w)) if t]
        if touched:
            if len(touched) == 1 and reg.area >= 0.7 * bh * bw:
                cut.append((reg.label, (r0, r1, c0, c1), touched[0]))
            continue
        side = math.sqrt(reg.area)
        if not (min_side <= side <= max_side) or not (0.8 <= bh / bw <= 1.25):
            continue
        b = 0.5 * (bh + bw)
        s2a = b * b / reg.area - 1.0  # (cos a + sin a)^2 = 1 + sin 2a for a square
        if not (-0.1 <= s2a <= 0.85):
            continue
        alpha = 0.5 * math.asin(min(max(s2a, 0.0), 1.0))
        out.append((reg.label, (r0, r1, c0, c1), side, alpha))
    return lab, out, cut


def _complete_cut(cut, alpha: float, min_side: int, max_side: int):
    """Whole-square bbox, side and alpha of squares cut by one border (tilt from the others)."""
    out = []
    k = math.cos(alpha) + math.sin(alpha)
    for own, (r0, r1, c0, c1), border in cut:
        full = (c1 - c0) if border in ("top", "bottom") else (r1 - r0)
        seen = (r1 - r0) if border in ("top", "bottom") else (c1 - c0)
        side = full / k
        if not (min_side <= side <= max_side) or not (0.5 * full <= seen <= full + 1):
            continue
        if border == "top":
            r0 = r1 - full
        elif border == "bottom":
            r1 = r0 + full
        elif border == "left":
            c0 = c1 - full
        else:
            c1 = c0 + full
        out.append((own, (r0, r1, c0, c1), side, alpha))
    return out


def _roi_ok(lab_same, lab_other, big_other, own, roi) -> bool:
    y0, y1, x0, x1 = roi
    same = lab_same[y0:y1, x0:x1]
    other = lab_other[y0:y1, x0:x1]
    return bool(np.all((same == 0) | (same == own)) and np.all((other == 0) | (other == big_other)))


def find_edge_rois(image, *, min_side: int = 16, max_side: int | None = None,
                   smooth: float = 1.0) -> list[dict]:
    """Slanted-edge ROIs on the sides of the slanted squares of a chart image.

    image: 2-D array (a sharp truth image works best; blurred captures work too);
    min_side / max_side: accepted square side lengths in pixels; smooth: Gaussian sigma (pixels)
    applied before the Otsu threshold. Returns a list of dicts ``{"roi": (y0, y1, x0, x1),
    "centre": (y, x) of the edge midpoint, "side": "left" | "right" | "top" | "bottom",
    "square": index}``, ordered by square then side. Raises ValueError for NaN or flat images.
    """
    from scipy.ndimage import gaussian_filter
    from skimage.filters import threshold_otsu

    a = np.asarray(image)
    if a.ndim != 2:
        raise ValueError(f"image must be 2-D (H, W), got shape {a.shape}")
    a = a.astype(np.float64)
    if not np.all(np.isfinite(a)):
        raise ValueError("image contains NaN or infinite values")
    if a.max() == a.min():
        raise ValueError("image is constant: no chart edges to find")
    h, w = a.shape
    max_side = max(h, w) // 2 if max_side is None else int(max_side)
    s = gaussian_filter(a, smooth) if smooth > 0 else a
    t = threshold_otsu(s)
    rois: list[dict] = []
    masks = (s < t, s > t)
    labs = [_square_candidates(m, min_side, max_side) for m in masks]
    alphas = [c[3] for lab in labs for c in lab[1]]
    alpha_cut = float(np.median(alphas)) if alphas else math.radians(5.0)
    nsq = 0
    for p in range(2):
        lab_same, whole, cut = labs[p]
        lab_other = labs[1 - p][0]
        counts = np.bincount(lab_other.ravel())
        big_other = int(np.argmax(counts[1:]) + 1) if counts.size > 1 else 0
        cands = whole + _complete_cut(cut, alpha_cut, min_side, max_side)
        for own, (r0, r1, c0, c1), side, alpha in cands:
            sa = side * math.sin(alpha)
            m = int(math.ceil(sa + 0.15 * side))  # clear of the corners
            found = False
            for name in ("left", "right", "top", "bottom"):
                half = 0.5 * side
                while half >= 6:
                    hh = int(round(half))
                    if name in ("left", "right"):
                        xe = c0 if name == "left" else c1 - sa
                        a0, a1 = max(r0 + m, 0), min(r1 - m, h)  # along the edge, clipped
                        roi = (a0, a1, int(xe - hh), int(math.ceil(xe + sa + hh)))
                        across = (roi[2], roi[3], w)
                    else:
                        ye = r0 if name == "top" else r1 - sa
                        a0, a1 = max(c0 + m, 0), min(c1 - m, w)
                        roi = (int(ye - hh), int(math.ceil(ye + sa + hh)), a0, a1)
                        across = (roi[0], roi[1], h)
                    inside = 0 <= across[0] and across[1] <= across[2]
                    if (inside and a1 - a0 >= max(8, 0.25 * side) and across[1] - across[0] >= 8
                            and _roi_ok(lab_same, lab_other, big_other, own, roi)):
                        y0, y1, x0, x1 = roi
                        cy = 0.5 * (y0 + y1 - 1) if name in ("left", "right") else ye + sa / 2
                        cx = xe + sa / 2 if name in ("left", "right") else 0.5 * (x0 + x1 - 1)
                        rois.append({"roi": roi, "centre": (float(cy), float(cx)),
                                     "side": name, "square": nsq})
                        found = True
                        break
                    half *= 0.8
            nsq += int(found)
    return rois


@dataclass
class FieldMTF:
    """Slanted-edge MTF in several ROIs across the field.

    rois: (N, 4) int (y0, y1, x0, x1); centres: (N, 2) edge midpoints (y, x) in pixels;
    radius: (N,) normalised field radius; mtf50: (N,) cycles/pixel (NaN where the measurement
    failed or the MTF never fell to 0.5); results: EdgeMTF or None per ROI; errors: message or
    None per ROI; shape: image shape; pixel_pitch: metres or None.
    """

    rois: np.ndarray
    centres: np.ndarray
    radius: np.ndarray
    mtf50: np.ndarray
    results: list[EdgeMTF | None] = field(repr=False)
    errors: list[str | None] = field(repr=False)
    shape: tuple[int, int] = (0, 0)
    pixel_pitch: float | None = None

    def summary(self) -> dict:
        """MTF50 at the field centre and edge and their ratio (edge / centre).

        Medians over the ROIs with normalised radius <= 1/3 (centre) and >= 2/3 (edge); where a
        group is empty (e.g. a chart with a star in the middle), over the ROIs within 0.1 of the
        smallest (largest) measured radius. ``centre_radius`` / ``edge_radius`` say where.
        """
        ok = np.isfinite(self.mtf50)
        # above Nyquist (0.5 cycles/pixel) an MTF50 says the edge was sharpened past what the
        # pixels sample (a reconstruction prior, ringing), not that the detail is resolved
        out: dict = {"n_rois": int(len(self.mtf50)), "n_measured": int(ok.sum()),
                     "n_above_nyquist": int(np.sum(self.mtf50[ok] > 0.5))}
        if not ok.any():
            out.update(centre_mtf50=float("nan"), edge_mtf50=float("nan"),
                       edge_over_centre=float("nan"))
            return out
        r, v = self.radius[ok], self.mtf50[ok]
        cm = r <= CENTRE_RADIUS if np.any(r <= CENTRE_RADIUS) else r <= r.min() + GROUP_SPAN
        em = r >= EDGE_RADIUS if np.any(r >= EDGE_RADIUS) else r >= r.max() - GROUP_SPAN
        out.update(centre_mtf50=float(np.median(v[cm])), edge_mtf50=float(np.median(v[em])),
                   edge_over_centre=float(np.median(v[em]) / np.median(v[cm])),
                   centre_radius=float(np.median(r[cm])), edge_radius=float(np.median(r[em])),
                   n_centre=int(cm.sum()), n_edge=int(em.sum()))
        if self.pixel_pitch is not None:
            k = 1.0 / (self.pixel_pitch * 1e3)
            out.update(centre_mtf50_lpmm=out["centre_mtf50"] * k,
                       edge_mtf50_lpmm=out["edge_mtf50"] * k)
        return out

    def positions(self, n: int = 4) -> list[int]:
        """Indices of up to ``n`` measured ROIs at distinct field radii spread from the centre
        to the edge (the ROI nearest to each of ``n`` evenly spaced target radii)."""
        ok = np.flatnonzero(np.isfinite(self.mtf50))
        if ok.size == 0:
            return []
        r = self.radius[ok]
        picked: list[int] = []
        for target in np.linspace(r.min(), r.max(), n):
            free = [i for i in range(ok.size) if not any(
                abs(r[i] - self.radius[j]) < 0.02 for j in picked)]
            if not free:
                break
            picked.append(int(ok[min(free, key=lambda i: abs(r[i] - target))]))
        return sorted(picked, key=lambda j: self.radius[j])


def field_mtf(image, rois=None, *, reference=None, pixel_pitch: float | None = None,
              oversample: int = 4, window: str = "hamming", progress: bool = False) -> FieldMTF:
    """MTF (and MTF50) in many slanted-edge ROIs across the field of ``image``.

    rois: list of (y0, y1, x0, x1) or of dicts from :func:`find_edge_rois`; None finds them on
    ``reference`` (e.g. the sharp truth of a chart, same shape) or else on ``image`` itself.
    A ROI whose measurement fails (edge washed out, no edge) gets MTF50 = NaN and its error
    message; the others are kept. Raises ValueError if there are no ROIs at all.
    """
    a = np.asarray(image)
    if a.ndim != 2:
        raise ValueError(f"image must be 2-D (H, W), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError("image contains NaN or infinite values")
    if rois is None:
        src = a if reference is None else np.asarray(reference)
        if src.shape != a.shape:
            raise ValueError(f"reference shape {src.shape} differs from image shape {a.shape}")
        rois = find_edge_rois(src)
        if not rois:
            raise ValueError("no slanted-edge squares found in the chart image")
    items = [r if isinstance(r, dict) else {"roi": r} for r in rois]
    if not items:
        raise ValueError("rois is empty: give at least one (y0, y1, x0, x1)")
    boxes, centres, results, errors = [], [], [], []
    from tqdm import tqdm

    for it in tqdm(items, desc="MTF", disable=not progress, leave=False):
        roi = check_roi(it["roi"], a.shape)
        boxes.append(roi)
        try:
            res = measure_edge(a, roi, oversample=oversample, window=window,
                               pixel_pitch=pixel_pitch)
            results.append(res)
            errors.append(None)
        except ValueError as exc:
            results.append(None)
            errors.append(str(exc))
        if "centre" in it:
            centres.append(tuple(it["centre"]))
        else:
            centres.append((0.5 * (roi[0] + roi[1] - 1), 0.5 * (roi[2] + roi[3] - 1)))
    centres_a = np.asarray(centres, float).reshape(-1, 2)
    radius = np.array([field_radius(y, x, a.shape) for y, x in centres_a])
    m50 = np.array([r.mtf50 if r is not None else np.nan for r in results], float)
    return FieldMTF(rois=np.asarray(boxes, int).reshape(-1, 4), centres=centres_a, radius=radius,
                    mtf50=m50, results=results, errors=errors, shape=tuple(a.shape),
                    pixel_pitch=pixel_pitch)
