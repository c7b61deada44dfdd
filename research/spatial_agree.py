import os, sys, functools
sys.path.insert(0, "benchmarks")
from torch_modulo.multishot import noisy, spatial
import bench_noise
A = float(os.environ["AGREE"])
noisy.neighbour_prediction = functools.partial(spatial.neighbour_prediction, agree=A)
bench_noise.main(sys.argv[1:])
