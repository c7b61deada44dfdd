import os, sys
sys.path.insert(0, "benchmarks")
from torch_modulo.singleshot.learned import solver
from torch_modulo.singleshot import unwrap as U
from torch_modulo.singleshot.learned.decoding import refine_band
W = os.environ["CELLW"]; CUTS = int(os.environ.get("CUTS", "1"))
orig_load, orig_refine, orig_moves = solver.load_model, solver.refine_photosites, solver.region_moves
def moves(plane, k, cost, first, u, bits):
    return orig_moves(plane, refine_band(plane, k, cost, first, bits, CUTS) if CUTS else k, cost, first, u, bits)
def refine(*a, **kw):
    solver.load_model = lambda path=None, device="cpu": orig_load(W, device=device)
    solver.region_moves = moves
    try:
        return orig_refine(*a, **kw)
    finally:
        solver.load_model, solver.region_moves = orig_load, orig_moves
U.refine_photosites = refine
import bench_cfa
bench_cfa.main()
