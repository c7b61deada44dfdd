"""Prototype (issue #34): frame-by-frame propagation of rollover counts into the pixels the spatial gate stops.

After each frame's gate of the spatial decoder (torch_modulo.multishot.noisy, ``shape`` given), a pixel that decoded
the frames before but fails the gate at this frame takes its count from its decoded 4-neighbours: the neighbour's
count plus the frame's wrapped difference, unwrapped by the difference of the two predictions (neighbour-refined, so
their difference is far sharper than either alone); it is accepted where at least MINAGREE decoded neighbours give
the same count and none disagrees, ITERS rounds per frame (the decoded region grows into the stopped one). It patches
the package's private ``noisy._decode`` and runs benchmarks/bench_noise.py (the whole plane as one band: the bands'
halo does not cover the propagation), so it runs from the repository root only:

    ITERS=32 MINAGREE=2 TAIL=1.1 python research/spatial_propagation.py --modulo-only --spatial --noise q16 --min-ratio 3

TAIL=R appends a last frame R times the plan's longest (then renormalised), to collect light near the longest exposure.
Results (all 39 dev scenes, 2026-12-07) are in docs/multishot.md, "What keeps q = 16 above 6 frames".
"""
import os, sys, math, torch
import torch.nn.functional as F
sys.path.insert(0, "benchmarks")
from torch_modulo.multishot import noisy
from torch_modulo.multishot.spatial import neighbour_prediction
import bench_noise

ITERS = int(os.environ.get("ITERS", "8"))
MINAGREE = int(os.environ.get("MINAGREE", "2"))
TAIL = float(os.environ.get("TAIL", "0"))
noisy._BAND = 1 << 30

def shift(a, dy, dx, fill):
    # value of the neighbour at (y+dy, x+dx) for each (y, x); `fill` outside
    p = F.pad(a, (1, 1, 1, 1), value=fill)
    h, w = a.shape[-2:]
    return p[..., 1 + dy:1 + dy + h, 1 + dx:1 + dx + w]

def _decode(x, exposures, t, dark, table, period, gate, whole, model, shape):
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
        ok = (spread <= gate) * (own + spread <= whole)
        prev = active
        active = active * ok
        half = x[:, i] + 0.5
        k = ((expected - half) / period).round_().clamp_min_(0.0)
        count = half + k * period
        if ITERS and shape is not None:
            cand = (prev > 0) & (active == 0)  # stopped at this frame
            dec = active.reshape(-1, h, w) > 0
            cnt = count.reshape(-1, h, w).clone()
            hv = half.reshape(-1, h, w)
            ex = expected.reshape(-1, h, w)
            cd = cand.reshape(-1, h, w).clone()
            for _ in range(ITERS):
                if not bool(cd.any()):
                    break
                votes = torch.zeros_like(cnt); nvote = torch.zeros_like(cnt); first = torch.full_like(cnt, float("nan")); clash = torch.zeros_like(cd)
                for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
                    qd = shift(dec.float(), dy, dx, 0.0) > 0
                    qc = shift(cnt, dy, dx, 0.0)
                    qh = shift(hv, dy, dx, 0.0)
                    qe = shift(ex, dy, dx, 0.0)
                    wrapped = hv - qh
                    predicted = ex - qe
                    n = ((predicted - wrapped) / period).round()
                    c = qc + wrapped + n * period
                    use = cd & qd
                    same = torch.isnan(first) | ((c - first).abs() < 0.5)
                    clash |= use & ~same
                    first = torch.where(use & torch.isnan(first), c, first)
                    nvote += use.float()
                accept = cd & (nvote >= MINAGREE) & ~clash
                if not bool(accept.any()):
                    break
                cnt = torch.where(accept, first, cnt)
                dec = dec | accept
                cd = cd & ~accept
            new = dec.reshape(active.shape).float()
            count = torch.where(new > active, cnt.reshape(count.shape), count)
            active = torch.maximum(active, new)
        decoded.append(active)
        counts.append(count)
        weight = active * (ti * ti) / model.variance(count.clamp_min(0.5) - 0.0) if False else active * (ti * ti) / own
        total = total + weight
        weighted = weighted + weight * counts[i] / ti
        used = used + active
    first = noisy._unclip(weighted / total, used, t, table)
    norm = torch.zeros_like(first); raw = torch.zeros_like(first)
    for i in range(m):
        ti = exposures[i]
        slope = decoded[i] / (first * model.per_count + model.floor / ti)
        norm = norm + slope * ti
        raw = raw + slope * counts[i]
    return noisy._unclip(raw / norm, used, t, table), 1.0 / norm, used

noisy._decode = _decode
if TAIL:
    orig = bench_noise.modulo_plan
    def plan(stops, noise, args):
        p = orig(stops, noise, args); p = p + [p[-1] * TAIL]; return [t / p[-1] for t in p]
    bench_noise.modulo_plan = plan
bench_noise.main(sys.argv[1:])
