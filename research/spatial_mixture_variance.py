import sys, math, torch
sys.path.insert(0, "benchmarks")
from torch_modulo.multishot import noisy
from torch_modulo.multishot.spatial import neighbour_prediction
import bench_noise
S = 1.0 / math.sqrt(2.0)
def _decode(x, exposures, t, dark, table, period, gate, whole, model, shape):
    m = x.shape[1]
    counts = [x[:, 0] + 0.5]
    used = torch.ones_like(counts[0]); active = torch.ones_like(used); decoded = [active]
    risk = [torch.zeros_like(used)]
    t0 = exposures[0]
    total = t0 * t0 / model.variance(counts[0]); weighted = total * counts[0] / t0
    for i in range(1, m):
        ti = exposures[i]; inverse = 1.0 / total
        if shape is None:
            expected = weighted * inverse * ti; own = model.variance(expected)
            s2 = own + inverse * ti * ti
            active = (s2 <= gate).float() * active
        else:
            guess, spread = neighbour_prediction(weighted * inverse, inverse, shape)
            expected = guess * ti; own = model.variance(expected); spread = spread * ti * ti
            s2 = own + spread
            active = (s2 <= whole).float() * (spread <= gate).float() * active
        decoded.append(active)
        risk.append(active * torch.erfc(period * 0.5 * S / s2.sqrt()))
        half = x[:, i] + 0.5
        k = ((expected - half) / period).round().clamp_min(0.0)
        counts.append(half + k * period)
        weight = active * ti * ti / own
        total = total + weight; weighted = weighted + weight * counts[i] / ti; used = used + active
    first = noisy._unclip(weighted / total, used, t, table)
    norm = torch.zeros_like(first); raw = torch.zeros_like(first); extra = torch.zeros_like(first)
    for i in range(m):
        ti = exposures[i]
        slope = decoded[i] / (first * model.per_count + model.floor / ti)
        norm = norm + slope * ti; raw = raw + slope * counts[i]
        extra = extra + risk[i] * (slope * period) ** 2
    return noisy._unclip(raw / norm, used, t, table), 1.0 / norm + extra / norm**2, used
noisy._decode = _decode
bench_noise.main(sys.argv[1:])
