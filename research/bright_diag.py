"""Diagnosis (issue #34): where does the bright third lose under a plan of larger ratios?

For each scene at q16: the plan (min_ratio, longest_frames from argv), decode_noisy with spatial evidence, the frames
each pixel used; for the bright third, the share that used every frame, and the median relative error of the
decoder against an all-frames oracle (every frame's true rollover count, the same least-squares weights).
"""
import os
import statistics
import sys

import torch

import torch_modulo as tm
from torch_modulo import protocols
from torch_modulo.multishot.noisy import decode_noisy
from torch_modulo.sensors import NoiseModel, SimulatedIntensitySensor, SimulatedModuloSensor

noise = NoiseModel(16.0, 16.0)
min_ratio = float(sys.argv[1])
longest = int(sys.argv[2])
limit = int(sys.argv[3]) if len(sys.argv) > 3 else 0
scenes = protocols.list_scenes(protocols.DEV_SCENES)
if limit:
    scenes = scenes[:limit]
rows = []
for i, path in enumerate(scenes):
    image = protocols.load_scene(path, 512)
    scale, stops = protocols.protocol_n(image)
    radiance = image * scale
    batch = radiance.unsqueeze(0)
    spatial = os.environ.get("PERPIX") is None
    plan = tm.plan_exposures(stops, 8, noise=noise, min_ratio=min_ratio, longest_frames=longest, spatial=spatial)
    taus = [t / plan[-1] for t in plan]
    moduli = SimulatedModuloSensor(8, noise, seed=1000 + i)(batch, taus).moduli
    counts = SimulatedIntensitySensor(53, noise, seed=1000 + i)(batch, taus).frames  # (1, M, C, H, W)
    c, h, w = radiance.shape
    m = len(taus)
    frames = moduli.reshape(1, m, c, h * w).permute(0, 2, 1, 3).reshape(c, m, h * w)
    tau = torch.tensor(taus, dtype=torch.float64).expand(c, m)
    est, var, used = decode_noisy(frames, tau, 8, noise, 3.0, False, (h, w))
    truth = radiance.reshape(c, h * w)
    # all-frames oracle: inverse-variance weights t/Var(I) at the truth's expected count
    cnt = counts.reshape(1, m, c, h * w).permute(0, 2, 1, 3).reshape(c, m, h * w)
    t = tau.unsqueeze(-1)
    varc = (truth.unsqueeze(1) * t * noise.electrons_per_count + noise.read_noise**2) / noise.electrons_per_count**2
    wgt = t / varc
    oracle = (wgt * cnt).sum(1) / (wgt * t).sum(1)
    # the ceiling oracle: a perfect prediction, each frame used while the frame's own noise passes the whole gate
    whole = (256 / 4.0) ** 2
    ok = torch.cumprod((varc <= whole).double(), 1)
    ok[:, 0] = 1.0
    ceil = (ok * wgt * cnt).sum(1) / (ok * wgt * t).sum(1)
    mask = truth > 0
    vals = truth[mask]
    order = torch.argsort(vals)
    bright = torch.tensor_split(order, 3)[2]
    rel = ((est[mask] - vals).abs() / vals)[bright]
    relo = ((oracle[mask] - vals).abs() / vals)[bright]
    relc = ((ceil[mask] - vals).abs() / vals)[bright]
    u = used[mask][bright]
    full = u == m
    stop_hist = torch.bincount((m - u).long(), minlength=m)[: m].tolist()
    row = dict(
        scene=path.stem[:24], stops=stops, frames=m, bright=float(rel.median()), oracle_all=float(relo.median()), ceiling=float(relc.median()),
        full=float(full.double().mean()), bright_full=float(rel[full].median()) if full.any() else float('nan'),
        bright_stopped=float(rel[~full].median()) if (~full).any() else float('nan'), missing=stop_hist,
    )
    rows.append(row)
    print(row, flush=True)
print("mean bright", statistics.mean(r["bright"] for r in rows), "oracle_all", statistics.mean(r["oracle_all"] for r in rows), "ceiling", statistics.mean(r["ceiling"] for r in rows),
      "full", statistics.mean(r["full"] for r in rows), "frames", statistics.mean(r["frames"] for r in rows))
