"""Research (issue #34): each frame's stopped pixels decoded as an image by graph cuts.

After a frame's spatial gate, the pixels that decoded every frame before, fail the prediction's gate and whose own
noise passes the whole gate (``own <= whole``) take their rollover count from a min-cut labelling: unary terms from
the (wide) prediction, ``(c_p - mu_p)^2 / 2 (spread_p + own_p)``, and Huber pair terms on the frame's own count
differences to their 4-neighbours that are candidates or decoded at the frame, ``rho((c_p - c_q - g_pq) / s_pq)``
with ``s_pq^2 = own_p + own_q`` and ``g_pq`` the predicted difference (``G=1``) or 0. The moves shift a set of
candidates by +1 or -1 period (each binary move exact: the pair terms are convex in the shift). A candidate is kept
where its count moved no more than ``KEEP`` periods from the per-pixel nearest and its final unary and pair terms
pass (``ACCEPT``).

It patches the private ``noisy._decode`` and runs ``benchmarks/bench_noise.py`` with the given arguments:

    PYTHONPATH=/work/main python research/multishot_mrf.py --modulo-only --noise q16 --min-ratio 3 --longest-frames 2
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import maxflow
import numpy as np
import torch

from torch_modulo.multishot import noisy
from torch_modulo.multishot.spatial import neighbour_prediction

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_noise  # noqa: E402

USE_G = os.environ.get("G", "1") == "1"
HUBER = float(os.environ.get("HUBER", "2.0"))
LAMBDA = float(os.environ.get("LAMBDA", "1.0"))
ROUNDS = int(os.environ.get("ROUNDS", "2"))
STATS = {"cand": 0, "kept": 0, "moved": 0}
SOLVER = os.environ.get("SOLVER", "cut")
GATE_FACTOR = float(os.environ.get("GATE_FACTOR", "0"))  # 0: no bound on the candidates' spread
AGREE = int(os.environ.get("AGREE", "0"))  # candidates kept with at least this many agreeing pairs
AGREE_Z = float(os.environ.get("AGREE_Z", "2.5"))
CFLOOR = float(os.environ.get("CFLOOR", "0"))
ICM_ROUNDS = int(os.environ.get("ICM_ROUNDS", "4"))


def _shifted(v, dy, dx, fill):
    """v (B, h, w) read at (y + dy, x + dx), ``fill`` beyond the border."""
    h, w = v.shape[-2:]
    p = torch.nn.functional.pad(v, (1, 1, 1, 1), value=fill)
    return p[:, 1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w]


_NB = ((0, 1), (0, -1), (1, 0), (-1, 0))


def pair_terms(c, mu, own, inside, shift):
    """Per pixel, the sum over its 4-neighbours inside of huber((c + shift - c_q - g) / s), and the agreeing count."""
    total = torch.zeros_like(c)
    agree = torch.zeros_like(c)
    for dy, dx in _NB:
        cq = _shifted(c, dy, dx, 0.0)
        inq = _shifted(inside, dy, dx, False)
        g = mu - _shifted(mu, dy, dx, 0.0) if USE_G else 0.0
        s = (own + _shifted(own, dy, dx, 1.0)).sqrt()
        z = (c + shift - cq - g) / s
        a = z.abs()
        hub = torch.where(a <= HUBER, 0.5 * z * z, HUBER * a - 0.5 * HUBER * HUBER)
        total = total + torch.where(inq, hub, 0.0)
        agree = agree + (inq & (a <= AGREE_Z)).to(c.dtype)
    return LAMBDA * total, agree


def icm_counts(half, k0, mu, spread, own, fixed, cand, period):
    """(B, h, w) tensors: the candidates' rollover counts by iterated conditional modes on checkerboards."""
    k = k0.clone()
    b, h, w = k.shape
    yy, xx = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    parity = ((yy + xx) % 2).expand(b, h, w)
    inside = cand | fixed
    uvar = 2.0 * (spread + own)
    for _ in range(ICM_ROUNDS):
        for par in (0, 1):
            c = half + k * period
            best = None
            for sh in (-1.0, 0.0, 1.0):
                e = (c + sh * period - mu) ** 2 / uvar + pair_terms(c, mu, own, inside, sh * period)[0]
                e = torch.where((k + sh) >= 0, e, float("inf"))
                if best is None:
                    best, arg = e, torch.full_like(e, sh)
                else:
                    better = e < best
                    best = torch.where(better, e, best)
                    arg = torch.where(better, torch.full_like(e, sh), arg)
            upd = cand & (parity == par)
            k = torch.where(upd, k + arg, k)
    return k


def huber(z: np.ndarray) -> np.ndarray:
    a = np.abs(z)
    return np.where(a <= HUBER, 0.5 * z * z, HUBER * a - 0.5 * HUBER * HUBER)


def mrf_counts(half, k0, mu, spread, own, fixed, cand, period):
    """One plane (H, W) numpy float64: the candidates' rollover counts by min-cut moves; returns k (H, W)."""
    k = k0.copy()
    h, w = k.shape
    unary_var = 2.0 * (spread + own)
    inside = cand | fixed
    pairs = []
    for dy, dx in ((0, 1), (1, 0)):
        a = (slice(0, h - dy), slice(0, w - dx))
        b = (slice(dy, h), slice(dx, w))
        use = inside[a] & inside[b] & (cand[a] | cand[b])
        s = np.sqrt(own[a] + own[b])
        g = (mu[a] - mu[b]) if USE_G else 0.0
        pairs.append((a, b, use, s, g))

    def energy_terms(kk):
        c = half + kk * period
        return c

    for _ in range(ROUNDS):
        changed = False
        for step in (1.0, -1.0):
            c = energy_terms(k)
            graph = maxflow.Graph[float]()
            ids = graph.add_grid_nodes((h, w))
            # unary: label 1 = shift by step
            u0 = (c - mu) ** 2 / unary_var
            u1 = (c + step * period - mu) ** 2 / unary_var
            big = 1e12
            cost1 = np.where(cand, u1, big)  # paid when label 1
            cost0 = np.where(cand, u0, 0.0)  # paid when label 0
            src = np.zeros((h, w))
            snk = np.zeros((h, w))
            for a, b, use, s, g in pairs:
                r = (c[a] - c[b] - g) / s
                d = step * period / s
                e00 = huber(r)
                e11 = e00
                e01 = huber(r - d)  # p not shifted, q shifted: c_p - (c_q + step P)
                e10 = huber(r + d)
                e00, e01, e10, e11 = (LAMBDA * np.where(use, x, 0.0) for x in (e00, e01, e10, e11))
                # E = e00 + (e10 - e00) a_p + (e11 - e10) a_q + (e01 + e10 - e00 - e11)(1 - a_p) a_q
                cost1_a = e10 - e00
                cost1_b = e11 - e10
                cost1[a] += cost1_a
                cost1[b] += cost1_b
                wgt = np.maximum(e01 + e10 - e00 - e11, 0.0)
                ww = np.zeros((h, w))
                ww[a] = wgt
                structure = np.zeros((3, 3))
                structure[1 + b[0].start, 1 + b[1].start] = 1
                graph.add_grid_edges(ids, weights=ww, structure=structure, symmetric=False)
            # linear terms: cost1 - cost0 paid for label 1
            diff = cost1 - cost0
            src += np.maximum(diff, 0.0)
            snk += np.maximum(-diff, 0.0)
            graph.add_grid_tedges(ids, src, snk)
            graph.maxflow()
            shift = graph.get_grid_segments(ids) & cand
            if shift.any():
                # keep counts >= 0
                newk = k + step * shift
                newk = np.maximum(newk, 0.0)
                if (newk != k).any():
                    changed = True
                k = newk
        if not changed:
            break
    return k


def _decode(x, exposures, t, dark, table, period, gate, whole, model, shape, row0=0):
    if shape is None:
        return ORIGINAL(x, exposures, t, dark, table, period, gate, whole, model, shape)
    m = x.shape[1]
    counts = [x[:, 0] + 0.5]
    used = torch.ones_like(counts[0])
    active = torch.ones_like(used)
    decoded = [active]
    t0 = exposures[0]
    total = t0 * t0 / model.variance(counts[0])
    weighted = total * counts[0] / t0
    h, w = shape
    for i in range(1, m):
        ti = exposures[i]
        inverse = 1.0 / total
        guess, spread = neighbour_prediction(weighted * inverse, inverse, shape)
        expected = guess * ti
        own = model.variance(expected)
        spread = spread * (ti * ti)
        ok = (own + spread <= whole) & (spread <= gate) & (active > 0)
        half = x[:, i] + 0.5
        k = ((expected - half) / period).round().clamp_min(0.0)
        cand = (active > 0) & ~ok & (own <= whole)
        if GATE_FACTOR:
            cand &= spread <= GATE_FACTOR * gate
        if CFLOOR:
            cand &= expected >= CFLOOR * period
        new_active = ok.clone()
        if SOLVER == "icm":
            view = lambda v: v.reshape(-1, h, w)  # noqa: E731
            kk = icm_counts(view(half), view(k), view(expected), view(spread), view(own), view(ok), view(cand), period)
            kk = kk.reshape(k.shape)
            STATS["cand"] += int(cand.sum())
            STATS["moved"] += int((kk != k)[cand].sum())
            k = torch.where(cand, kk, k)
            keep = cand
            if AGREE:
                _, agree = pair_terms(view(half + k * period), view(expected), view(own), view(ok | cand), 0.0)
                keep = cand & (agree.reshape(k.shape) >= AGREE)
            STATS["kept"] += int(keep.sum())
            new_active |= keep
        for b in range(x.shape[0] if SOLVER == "cut" else 0):
            cb = cand[b].reshape(h, w).numpy()
            if not cb.any():
                continue
            arr = lambda v: v[b].reshape(h, w).double().numpy()  # noqa: E731
            kk = mrf_counts(arr(half), arr(k), arr(expected), arr(spread), arr(own),
                            ok[b].reshape(h, w).numpy(), cb, period)
            kk_t = torch.from_numpy(kk).reshape(-1).to(k.dtype)
            STATS["cand"] += int(cb.sum())
            STATS["moved"] += int((kk_t != k[b])[cand[b]].sum())
            k[b] = torch.where(cand[b], kk_t, k[b])
            keep = cand[b]
            if AGREE:
                view = lambda v: v[b].reshape(1, h, w)  # noqa: E731
                _, agree = pair_terms(view(half + k * period), view(expected), view(own), view(ok | cand), 0.0)
                keep = keep & (agree.reshape(-1) >= AGREE)
            new_active[b] |= keep
            STATS["kept"] += int(keep.sum())
        active = new_active.to(used.dtype)
        decoded.append(active)
        counts.append(half + k * period)
        weight = active * (ti * ti) / own
        total = total + weight
        weighted = weighted + weight * counts[i] / ti
        used = used + active
    first = noisy._unclip(weighted / total, used, t, table)
    norm = torch.zeros_like(first)
    raw = torch.zeros_like(first)
    for i in range(m):
        ti = exposures[i]
        slope = decoded[i] / (first * model.per_count + model.floor / ti)
        norm = norm + slope * ti
        raw = raw + slope * counts[i]
    return noisy._unclip(raw / norm, used, t, table), 1.0 / norm, used


ORIGINAL = noisy._decode
if os.environ.get("MRF", "1") == "1":
    noisy._decode = _decode
from torch_modulo.multishot import planning  # noqa: E402

if "SLACK" in os.environ:
    planning._LIMIT_SLACK = float(os.environ["SLACK"])
if "SHRINK" in os.environ:
    planning.PLANNED_SHRINK = float(os.environ["SHRINK"])
if os.environ.get("WHOLE_LIMIT") == "1":
    # the MRF decodes up to the whole gate whatever the ratio: the physical limit of a pixel is the whole gate
    def _spatial_min_ratio(min_ratio: float, limit: float) -> float:
        whole = 1.0 / planning.WHOLE_SHARE**2
        target = planning._LIMIT_SLACK * planning._limit_error(min_ratio, 1.0 / min_ratio)
        low, high = min_ratio, limit
        if planning._limit_error(high, whole) <= target:
            return high
        for _ in range(60):
            mid = 0.5 * (low + high)
            low, high = (mid, high) if planning._limit_error(mid, whole) <= target else (low, mid)
        return max(low, min_ratio)

    planning._spatial_min_ratio = _spatial_min_ratio

if __name__ == "__main__":
    code = bench_noise.main(sys.argv[1:])
    print(STATS)
    raise SystemExit(code)
