import sys, torch
sys.path.insert(0, "benchmarks")
from torch_modulo.multishot import noisy
from torch_modulo.multishot.spatial import neighbour_prediction
import bench_noise
noisy._BAND = 1 << 30
STATS = {}
orig = noisy._decode
def _decode(x, exposures, t, dark, table, period, gate, whole, model, shape):
    if shape is not None:
        m = x.shape[1]
        c0 = x[:, 0] + 0.5
        active = torch.ones_like(c0)
        total = exposures[0]**2 / model.variance(c0); weighted = total * c0 / exposures[0]
        for i in range(1, m):
            ti = exposures[i]; inv = 1/total
            guess, spread = neighbour_prediction(weighted*inv, inv, shape)
            exp_ = guess*ti; own = model.variance(exp_); spread = spread*ti*ti
            a_s = spread <= gate; a_w = (own+spread) <= whole
            prev = active > 0
            key = (m, i)
            s = STATS.setdefault(key, [0,0,0,0])
            s[0] += int(prev.sum()); s[1] += int((prev & ~a_s).sum()); s[2] += int((prev & a_s & ~a_w).sum()); s[3] += int((prev & ~a_s & (own <= whole)).sum())
            active = active * a_s * a_w
            half = x[:, i] + 0.5
            k = ((exp_-half)/period).round().clamp_min(0)
            cnt = half + k*period
            w = active*ti*ti/own; total = total + w; weighted = weighted + w*cnt/ti
    return orig(x, exposures, t, dark, table, period, gate, whole, model, shape)
noisy._decode = _decode
bench_noise.main(sys.argv[1:])
for k in sorted(STATS):
    s = STATS[k]; print(k, "active_before", s[0], "fail_spread_only %.4f" % (s[1]/max(s[0],1)), "fail_whole_only %.4f" % (s[2]/max(s[0],1)), "spreadfail_but_own_ok %.4f" % (s[3]/max(s[0],1)))
