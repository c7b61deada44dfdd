"""Prototype (#34): each frame's stopped pixels unwrapped region by region.

Per frame, after the spatial gate: candidates = pixels that decoded the frames before, fail the gate, and whose own
noise passes.  Pairs (4-neighbours) among accepted+candidates are linked when the count difference predicted from a
telescoped local gradient of the running estimates (window 2R+1) unwraps the frame's wrapped difference safely
(variance gate), and no 2x2 loop through the pair has a residue.  Components by min-label propagation carry
potentials (counts up to one unknown offset); the offset is the variance-weighted mean of the raw per-pixel
predictions over the component (independent errors), accepted when its variance passes the gate and the accepted
pixels of the component agree with it.
"""
import os, sys, math, time, torch
import torch.nn.functional as F
sys.path.insert(0, "benchmarks")
from torch_modulo.multishot import noisy
from torch_modulo.multishot.spatial import neighbour_prediction
import bench_noise

R = int(os.environ.get("R", "3"))
ITERS = int(os.environ.get("ITERS", "200"))
PAIRGATE = float(os.environ.get("PAIRGATE", "1.0"))  # share of gate for pair links
AGREE = float(os.environ.get("AGREE", "0.99"))
MINSIZE = int(os.environ.get("MINSIZE", "1"))
noisy._BAND = 1 << 30
STATS = {}
TIME = [0.0]

def box(a, ry, rx):
    # sum over window rows y-ry..y+ry, cols x-rx..x+rx, NaN where the window leaves the image
    k = torch.ones(1, 1, 2 * ry + 1, 2 * rx + 1, dtype=a.dtype)
    return F.conv2d(F.pad(a[:, None], (rx, rx, ry, ry), value=math.nan), k)[:, 0]

def shifted(a, dy, dx, fill):
    h, w = a.shape[-2:]
    p = F.pad(a, (1, 1, 1, 1), value=fill)
    return p[..., 1 + dy:1 + dy + h, 1 + dx:1 + dx + w]

def region_pass(cnt, act, cand, half, e_raw, v_raw, tvar, own, ti, period, gate):
    """cnt/act/cand/half/own: (P, h, w); e_raw: raw estimate E; v_raw: Var(E). Returns new counts, new active."""
    n = (2 * R + 1)
    # gradient per pixel (telescoped): (mean col x+R - mean col x-R) / 2R over rows y-R..y+R
    colsum = box(e_raw, R, 0)  # sum over 2R+1 rows
    gx = (shifted_far(colsum, 0, R) - shifted_far(colsum, 0, -R)) / (n * 2 * R)
    rowsum = box(e_raw, 0, R)
    gy = (shifted_far(rowsum, R, 0) - shifted_far(rowsum, -R, 0)) / (n * 2 * R)
    vbox = box(v_raw, R, R) / (n * n)  # mean variance in window
    vg = 2 * vbox / (n * (2 * R) ** 2)  # variance of a gradient estimate
    use = (act > 0) | cand
    links = []
    for (dy, dx, g) in ((0, 1, gx), (1, 0, gy)):
        q_use = shifted(use.float(), dy, dx, 0.0) > 0
        q_half = shifted(half, dy, dx, 0.0)
        q_own = shifted(own, dy, dx, 0.0)
        gq = shifted(g, dy, dx, math.nan)
        vq = shifted(vg, dy, dx, math.nan)
        pred = 0.5 * (g + gq) * ti
        pvar = 0.5 * (vg + vq) * ti * ti  # conservative (correlated)
        wrapped = q_half - half
        j = ((pred - wrapped) / period).round()
        d = wrapped + j * period  # count_q - count_p
        ok = use & q_use & torch.isfinite(pred) & ((pvar + own + q_own) <= PAIRGATE * gate)
        links.append((dy, dx, ok, d))
    # residues on 2x2 plaquettes: p -> right -> down-right ; p -> down -> down-right
    (_, _, okx, dxd), (_, _, oky, dyd) = links
    okx_below = shifted(okx.float(), 1, 0, 0.0) > 0
    dx_below = shifted(dxd, 1, 0, 0.0)
    oky_right = shifted(oky.float(), 0, 1, 0.0) > 0
    dy_right = shifted(dyd, 0, 1, 0.0)
    full = okx & oky & okx_below & oky_right
    resid = full & ((dxd + dy_right - dyd - dx_below).abs() > 0.5)
    # remove edges of residue plaquettes
    bad = resid.float()
    okx = okx & ~(bad > 0) & ~(shifted(bad, -1, 0, 0.0) > 0)
    oky = oky & ~(bad > 0) & ~(shifted(bad, 0, -1, 0.0) > 0)
    P_, h, w = half.shape
    idx = torch.arange(h * w, dtype=torch.float64).reshape(1, h, w).expand(P_, h, w).clone()
    label = torch.where(use, idx, torch.full_like(idx, math.inf))
    phi = half.double().clone()
    # directed neighbour edges: (dy, dx, ok mask for edge p->q, count diff q-p)
    okx_l = shifted(okx.float(), 0, -1, 0.0) > 0; dxd_l = -shifted(dxd, 0, -1, 0.0)
    oky_u = shifted(oky.float(), -1, 0, 0.0) > 0; dyd_u = -shifted(dyd, -1, 0, 0.0)
    edges = [(0, 1, okx, dxd), (1, 0, oky, dyd), (0, -1, okx_l, dxd_l), (-1, 0, oky_u, dyd_u)]
    for it in range(ITERS):
        changed = False
        for dy, dx, ok, d in edges:
            ql = shifted(label, dy, dx, math.inf)
            qphi = shifted(phi, dy, dx, 0.0)
            take = ok & (ql < label)
            if bool(take.any()):
                changed = True
                label = torch.where(take, ql, label)
                phi = torch.where(take, qphi - d.double(), phi)
        if not changed:
            break
    STATS.setdefault("iters", []).append(it)
    # component offset
    lab = label.reshape(-1)
    valid = torch.isfinite(lab)
    li = torch.where(valid, lab, torch.zeros_like(lab)).long() + (torch.arange(P_).repeat_interleave(h * w) * h * w)
    z = (e_raw.double() * ti - phi).reshape(-1)
    var = (tvar.double()).reshape(-1)
    wts = torch.where(valid, 1.0 / var, torch.zeros_like(var))
    nl = P_ * h * w
    sw = torch.zeros(nl, dtype=torch.float64).index_add_(0, li, wts)
    swz = torch.zeros(nl, dtype=torch.float64).index_add_(0, li, wts * z)
    size = torch.zeros(nl, dtype=torch.float64).index_add_(0, li, valid.double())
    K = torch.round(swz / sw.clamp_min(1e-300) / period)
    vK = 1.0 / sw.clamp_min(1e-300)
    # agreement of accepted pixels
    a = (act > 0).reshape(-1) & valid
    c_new = phi.reshape(-1) + K[li] * period
    agree_ = (c_new - cnt.double().reshape(-1)).abs() < 0.5
    na = torch.zeros(nl, dtype=torch.float64).index_add_(0, li, a.double())
    nagree = torch.zeros(nl, dtype=torch.float64).index_add_(0, li, (a & agree_).double())
    good = (vK <= gate) & ((na == 0) | (nagree >= AGREE * na)) & (size >= MINSIZE)
    accept = cand.reshape(-1) & valid & good[li] & (c_new > 0)
    newcnt = torch.where(accept, c_new.to(cnt.dtype), cnt.reshape(-1)).reshape(cnt.shape)
    return newcnt, accept.reshape(cand.shape)

def shifted_far(a, dy, dx):
    h, w = a.shape[-2:]
    r = max(abs(dy), abs(dx))
    p = F.pad(a, (r, r, r, r), value=math.nan)
    return p[..., r + dy:r + dy + h, r + dx:r + dx + w]

def _decode(x, exposures, t, dark, table, period, gate, whole, model, shape):
    if shape is None:
        return orig(x, exposures, t, dark, table, period, gate, whole, model, shape)
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
        cand = (prev > 0) & (active == 0) & (own <= gate)
        if bool(cand.any()):
            t1 = time.perf_counter()
            sh = (-1, h, w)
            e_raw = (weighted * inverse).reshape(sh)
            v_raw = inverse.reshape(sh)
            tvar = v_raw * ti * ti + own.reshape(sh)
            newcnt, acc = region_pass(count.reshape(sh), active.reshape(sh), cand.reshape(sh), half.reshape(sh),
                                      e_raw, v_raw, tvar, own.reshape(sh), ti, period, gate)
            TIME[0] += time.perf_counter() - t1
            if not torch.isfinite(newcnt[acc]).all(): print('nonfinite', int((~torch.isfinite(newcnt[acc])).sum()), int(acc.sum()))
            s = STATS.setdefault((m, i), [0, 0]); s[0] += int(cand.sum()); s[1] += int(acc.sum())
            count = newcnt.reshape(count.shape)
            active = torch.maximum(active, acc.reshape(active.shape).float())
        decoded.append(active)
        counts.append(count)
        weight = active * (ti * ti) / own
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

orig = noisy._decode
noisy._decode = _decode
bench_noise.main(sys.argv[1:])
for k in sorted(x for x in STATS if x != "iters"):
    print(k, STATS[k], "%.3f" % (STATS[k][1] / max(1, STATS[k][0])))
it = STATS.get("iters", [0])
print("region time %.1f s, iters max %d mean %.1f" % (TIME[0], max(it), sum(it) / len(it)))
