"""Path following: the rollover counts ``k`` of a modulus image integrated along its most reliable pairs.

This is the default single-shot method (``method="guided"``) and the starting point of ``"fast"`` on smooth
images. :func:`quality_guided_k` is reliability-guided path following in the spirit of Herraez et al. (Applied
Optics 2002, the algorithm behind scikit-image's ``unwrap_phase``): every pixel gets a reliability from the
second differences of the wrapped image, neighbour pairs are joined from the most reliable down (Kruskal's
algorithm, i.e. a minimum spanning tree), and ``k`` is integrated along the tree with the wrapped
differences. It runs in whole-array numpy/scipy calls: the tree is scipy's ``minimum_spanning_tree`` and the
integration is pointer jumping (``log2`` of the tree depth passes over the pixels).

:func:`quality_guided_colour_k` does the same for the channels of one colour image together: the channels share
their edges, so the second differences of all channels are summed into one reliability and every channel is
integrated along the same tree (a step that is steep in one channel is avoided in all of them).
"""

from __future__ import annotations

import numpy as np

from torch_modulo.singleshot.grid import integrate_wrapped, pair_indices, pair_slices, spanning_tree, wrapped_difference

__all__ = [
    "quality_guided_colour_k",
    "quality_guided_k",
    "residue_density",
    "smooth_wrapped",
]


def residue_density(modulus: np.ndarray, bits: int) -> float:
    """Share of 2 x 2 loops whose wrapped differences do not sum to zero (phase-unwrapping *residues*).

    Without residues the wrapped differences integrate to the same image along every path, so path following
    recovers a smooth image exactly; natural scenes with edges steeper than half a period have many.
    """
    m = np.asarray(modulus, dtype=np.int64)
    if m.shape[0] < 2 or m.shape[1] < 2:
        return 0.0
    period = 1 << bits
    loop = (
        wrapped_difference(m[:-1, 1:] - m[:-1, :-1], period)
        + wrapped_difference(m[1:, 1:] - m[:-1, 1:], period)
        + wrapped_difference(m[1:, :-1] - m[1:, 1:], period)
        + wrapped_difference(m[:-1, :-1] - m[1:, :-1], period)
    )
    return float(np.count_nonzero(loop) / loop.size)


def _second_difference_quality(modulus: np.ndarray, period: int) -> np.ndarray:
    """Herraez's ``D``: root sum of squared wrapped second differences (lower is more reliable).

    Border pixels use the second differences that fit inside the image; a pixel with none gets 0.
    """
    h, w = modulus.shape
    m = modulus if np.issubdtype(modulus.dtype, np.floating) else modulus.astype(np.int64)
    acc = np.zeros((h, w))
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        # Second difference along (dy, dx) at the centre pixel: wrap(I[-1] - I[0]) - wrap(I[0] - I[+1]).
        y0, y1 = dy, h - dy
        x0, x1 = max(dx, -dx), w - max(dx, -dx)
        if y1 <= y0 or x1 <= x0:
            continue
        centre = m[y0:y1, x0:x1]
        before = m[y0 - dy : y1 - dy, x0 - dx : x1 - dx]
        after = m[y0 + dy : y1 + dy, x0 + dx : x1 + dx]
        sd = wrapped_difference(before - centre, period) - wrapped_difference(centre - after, period)
        acc[y0:y1, x0:x1] += sd.astype(np.float64) ** 2
    return np.sqrt(acc)


def _reliability_tree(difficulty: np.ndarray) -> np.ndarray:
    """Parent of every pixel in the most reliable spanning tree (Kruskal on 4-neighbour pairs), rooted at pixel 0.

    ``difficulty`` is Herraez's ``D`` (lower is more reliable); a pair's weight is ``1 / (R_i + R_j)`` with
    ``R = 1 / (D + 1e-3)``, so the minimum spanning tree joins the most reliable pairs first.
    """
    h, w = difficulty.shape
    inv_d = 1.0 / (difficulty + 1e-3)
    rows, cols, weights = [], [], []
    for off in ((0, 1), (1, 0)):
        i, j = pair_indices(h, w, off)
        first, second = pair_slices(h, w, off)
        rows.append(i)
        cols.append(j)
        # Kruskal joins the most reliable pair first: weight = 1 / (R_i + R_j) > 0 (zero means "no edge").
        weights.append((1.0 / (inv_d[first] + inv_d[second])).ravel())
    return spanning_tree(h * w, np.concatenate(rows), np.concatenate(cols), np.concatenate(weights))


def smooth_wrapped(modulus: np.ndarray, period: int, sigma: float) -> np.ndarray:
    """Denoise a wrapped image: Gaussian-smooth its phasor ``exp(2 pi i I_m / period)`` (``sigma`` pixels).

    Returns real values in ``[0, period)``. Smoothing the phasor, not the values, keeps the rollovers intact.
    """
    from scipy.ndimage import gaussian_filter

    phase = np.asarray(modulus, dtype=np.float64) * (2 * np.pi / period)
    re = gaussian_filter(np.cos(phase), sigma, mode="nearest")
    im = gaussian_filter(np.sin(phase), sigma, mode="nearest")
    out = np.mod(np.arctan2(im, re) * (period / (2 * np.pi)), period)
    return np.where(out >= period, 0.0, out)  # np.mod of a tiny negative number rounds up to ``period``


def quality_guided_k(modulus: np.ndarray, bits: int) -> np.ndarray:
    """Rollover counts from reliability-guided path following (Herraez et al. 2002), up to a constant.

    Args:
        modulus: (H, W) integer-valued array in ``[0, 2**bits)``.
        bits: the sensor bit depth ``N``.

    Returns:
        int64 (H, W) ``k``, with ``k = 0`` at the first pixel (the caller re-anchors it).
    """
    return quality_guided_colour_k(np.asarray(modulus)[None], bits)[0]


def quality_guided_colour_k(moduli: np.ndarray, bits: int, denoise: float = 0.0) -> np.ndarray:
    """Path following for the channels of one image on one shared tree: reliabilities summed over channels.

    With one channel this is :func:`quality_guided_k`. A step that is steep in one channel is avoided in all of
    them, which helps where an edge that rolls one channel over is visible in another.

    With ``denoise > 0`` the tree and the integration use the wrapped images smoothed by :func:`smooth_wrapped`
    (Gaussian of ``denoise`` pixels), and each pixel then takes the ``k`` that puts its own count nearest to the
    smooth estimate: robust to noise in the low bits (the paper's Fig. 14) at the price of fine detail.

    Args:
        moduli: (C, H, W) integer-valued array in ``[0, 2**bits)``: the channels of one image.
        bits: the sensor bit depth ``N``.
        denoise: the smoothing's standard deviation in pixels (0: none).

    Returns:
        int64 (C, H, W) ``k``, with ``k = 0`` at the first pixel of every channel (the caller re-anchors it).
    """
    moduli = np.asarray(moduli).astype(np.int64)
    c, h, w = moduli.shape
    if h * w <= 1:
        return np.zeros((c, h, w), dtype=np.int64)
    period = 1 << bits
    planes = [smooth_wrapped(m, period, denoise) for m in moduli] if denoise > 0 else list(moduli)
    difficulty = sum(_second_difference_quality(m, period) for m in planes)
    parent = _reliability_tree(difficulty)
    k = np.stack([integrate_wrapped(m, parent, period) for m in planes])
    if denoise > 0:
        estimate = np.stack(planes) + period * k
        k = np.rint((estimate - moduli) / period).astype(np.int64)
    return k
