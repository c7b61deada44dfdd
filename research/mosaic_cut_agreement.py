import os, sys, time, numpy as np, torch
sys.path.insert(0, "benchmarks")
from torch_modulo.singleshot.learned import solver
from torch_modulo.singleshot import unwrap as U
from torch_modulo.singleshot.learned.decoding import refine_band
from torch_modulo.cfa import split_planes, merge_planes, cfa_colours
CUTS = int(os.environ.get("CUTS", "1"))
MODE = os.environ.get("MODE", "agree")
CELLS = int(os.environ.get("CELLS", "0"))
orig_moves = solver.region_moves
def moves(plane, k, cost, first, u, bits):
    k2 = refine_band(plane, k, cost, first, bits, CUTS) if CUTS else k
    return orig_moves(plane, k2, cost, first, u, bits)

def refine(modulus, restored, spec, cfa, info):
    h, w = modulus.shape[-2:]
    planes = split_planes(modulus.reshape(-1, 1, h, w))
    moduli = planes.to(device="cpu", dtype=torch.int64)
    period = spec.params.period
    k = ((split_planes(restored.reshape(-1, 1, h, w)).double() - moduli) / period).round()
    colours = cfa_colours(cfa)
    r, b = colours.index(0), colours.index(2)
    g1, g2 = (i for i, c in enumerate(colours) if c == 1)
    solver.region_moves = moves
    try:
        for item in range(len(k)):
            res = []
            for image in ([r, g1, b], [r, g2, b]):
                guide = k[item, image].to(torch.int64).numpy()
                moved = solver.refine_photosites(planes[item, image], guide, spec, (0, 1, 2))
                res.append((guide, np.stack([U._keep_anchor(moved[i], guide[i]) for i in range(3)])))
            (ga, ma), (gb, mb) = res
            if MODE == "agree":
                rr = np.where(ma[0] == mb[0], ma[0], ga[0])
                bb = np.where(ma[2] == mb[2], ma[2], ga[2])
                same_g = (ma[1] - ga[1]) == (mb[1] - gb[1])
                gg1 = np.where(same_g, ma[1], ga[1]); gg2 = np.where(same_g, mb[1], gb[1])
            else:
                rr, bb, gg1, gg2 = ma[0], ma[2], ma[1], mb[1]
            if CELLS:
                cells_out, _ = U._solve_cells(modulus.reshape(-1, 1, h, w)[item:item + 1], spec, None, cfa)
                kc = ((split_planes(cells_out.reshape(1, 1, h, w)).double()[0] - moduli[item]) / period).round().long().numpy()
                vals = {}
                for plane, val in ((r, rr), (b, bb), (g1, gg1), (g2, gg2)):
                    g0 = k[item, plane].long().numpy()
                    c = U._keep_anchor(kc[plane], g0)
                    vals[plane] = np.where(val == c, val, g0)
                rr, bb, gg1, gg2 = vals[r], vals[b], vals[g1], vals[g2]
            for plane, val in ((r, rr), (b, bb), (g1, gg1), (g2, gg2)):
                k[item, plane] = torch.from_numpy(val).double()
    finally:
        solver.region_moves = orig_moves
    out = merge_planes(moduli + period * k).reshape(restored.shape)
    return out.to(dtype=restored.dtype)
U._refine_photosites = refine
import bench_cfa
bench_cfa.main()
