"""Train the edge-jump network of ``unwrap_single(method="learned")``: writes its weights and a summary of the run.

One command, seeded, from the repository root:

    python -m references.learned_single.train --out torch_modulo/singleshot/weights --minutes 60

Training pairs are built on the fly: a random crop of a radiance map (random scale, flips and quarter turns), seen
as luminance or RGB, scaled so that its brightest region rolls over 2 to 20 times, captured with the library's own
sensor (``capture_intensity`` at a high bit depth, clipped at the chosen peak, then ``modulo_wrap`` to 8 bits;
optionally with shot and read noise). With ``--mosaic``, a share of the samples is seen as a Bayer mosaic would be
by ``unwrap_single(..., cfa=...)``: mosaicked, wrapped and interpolated on the circle (:func:`mosaic_pair`).
Radiance maps come ONLY from the CC0/BSD scenes
(``protocols.list_scenes(DEV_SCENES, split="train")``: polyhaven-cc0 and openexr-images) and from procedural
scenes (:mod:`references.learned_single.procedural`): the validation scenes are never read here.

The loss is ``learned.edge_loss``: cross-entropy over the jump of every horizontal and vertical pair, weighted up
on the pairs whose wrapped step is wrong. Adam with a cosine learning rate over ``--steps`` (or over as many steps
as fit in ``--minutes``, measured on the first steps and written to the model card, so ``--steps`` reproduces a
run exactly). Logs to stdout.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from references.learned_single.procedural import procedural_scene
from torch_modulo import protocols
from torch_modulo.capture import capture_intensity, modulo_wrap
from torch_modulo.cfa import CFA_PATTERNS, demosaic, interpolate_wrapped, mosaic
from torch_modulo.singleshot.learned import EdgeJumpNet, edge_features, edge_loss, edge_targets
from torch_modulo.tonemap import luminance

BITS = 8
PERIOD = 2**BITS


def load_train_scenes(max_side: int, folder: Path = protocols.DEV_SCENES) -> list[torch.Tensor]:
    """The CC0/BSD training scenes below ``folder`` (its polyhaven-cc0 and openexr-images folders) as (3, H, W)
    float32 radiance (grey scenes repeated), longer side <= max_side."""
    scenes = []
    for path in protocols.list_scenes(folder, split="train"):
        assert protocols.scene_split(path, folder) == "train"
        image = protocols.load_scene(path, max_side).float()
        if image.shape[0] == 1:
            image = image.expand(3, -1, -1).contiguous()
        scenes.append(image)
    return scenes


def random_crop(
    scenes: list[torch.Tensor],
    size: int,
    rng: np.random.Generator,
    scales: tuple[int, ...] = (1, 2, 2),
    with_index: bool = False,
) -> torch.Tensor | tuple[torch.Tensor, int]:
    """A (3, size, size) crop of a random scene, flipped and turned, area-averaged by a factor drawn from ``scales``
    (with ``with_index``, also the scene's index).

    A factor the scene is too small for falls back to the largest that fits (1 at least).
    """
    index = int(rng.integers(len(scenes)))
    image = scenes[index]
    factor = int(rng.choice(scales))
    _, h, w = image.shape
    while factor > 1 and min(h, w) < size * factor:
        factor -= 1
    if min(h, w) < size:
        image = F.interpolate(image[None], scale_factor=size / min(h, w) + 0.01, mode="bilinear")[0]
        _, h, w = image.shape
    span = size * factor
    y, x = rng.integers(0, h - span + 1), rng.integers(0, w - span + 1)
    crop = image[:, y : y + span, x : x + span]
    if factor > 1:
        crop = F.avg_pool2d(crop[None], factor)[0]
    if rng.random() < 0.5:
        crop = crop.flip(-1)
    crop = torch.rot90(crop, int(rng.integers(4)), (-2, -1)).contiguous()
    return (crop, index) if with_index else crop


def exposure_references(image: torch.Tensor) -> dict[bool, dict[float, float]]:
    """The percentiles :func:`capture_pair` may expose a crop by, taken over a whole (3, H, W) scene: ``{grey:
    {q: value}}`` for its luminance (``grey``) and its RGB values, ``q`` in 99.9, 99 and 100."""
    out = {}
    for grey, x in ((True, luminance(image[None])[0]), (False, image)):
        values = x.double().clamp_min(0.0).numpy()
        out[grey] = {q: float(np.percentile(values, q)) for q in (99.9, 99.0, 100.0)}
    return out


def capture_pair(
    radiance: torch.Tensor,
    rng: np.random.Generator,
    noise: float,
    scene: dict[bool, dict[float, float]] | None = None,
) -> torch.Tensor:
    """True counts (C, H, W) of one crop: grey (luminance) or RGB, brightest region 2 to 20 rollovers.

    The exposure maps a high percentile of the crop (99.9th, 99th or the maximum) to a peak of ``256 w`` counts,
    ``w`` log-uniform in [2, 20]; counts saturate at that peak. With ``scene`` (:func:`exposure_references` of the
    scene the crop comes from), the percentile is the whole scene's, as a camera exposes a whole frame: the crop
    itself may then hold anything from no rollover to the saturated peak. With probability ``noise``, shot noise (1
    to 16 electrons per count) and as much read noise are added before the floor.
    """
    grey = rng.random() < 0.5
    x = luminance(radiance[None])[0] if grey else radiance
    x = x.double().clamp_min(0.0)
    peak = PERIOD * math.exp(rng.uniform(math.log(2.0), math.log(20.0)))
    q = float(rng.choice([99.9, 99.0, 100.0]))
    ref = (scene[grey][q] if scene else 0.0) or float(np.percentile(x.numpy(), q)) or float(x.max()) or 1.0
    exposure = peak / ref
    if rng.random() < noise:
        e = x * exposure
        electrons = float(np.exp(rng.uniform(0.0, math.log(16.0))))
        g = torch.Generator().manual_seed(int(rng.integers(2**31)))
        e = e + torch.randn(e.shape, generator=g, dtype=e.dtype) * torch.sqrt(e / electrons + 1.0)
        x, exposure = e.clamp_min(0.0), 1.0
    counts = capture_intensity(x, exposure, bits=20)
    return counts.clamp_max(math.floor(peak))


def mosaic_pair(counts: torch.Tensor, cfa: str) -> tuple[torch.Tensor, torch.Tensor]:
    """What ``unwrap_single(..., cfa=cfa)`` sees of (3, H, W) true counts, and the counts it should restore.

    The counts are mosaicked and wrapped, then interpolated on the circle (``interpolate_wrapped``): that guide is
    the network's input. Its target agrees with the true counts at the photosites; elsewhere it is the bilinear
    interpolation of the true photosite counts, moved by whole periods to be congruent with the guide.
    """
    sites = mosaic(counts, cfa)
    guide = interpolate_wrapped(modulo_wrap(sites, BITS), cfa, BITS)
    smooth = demosaic(sites, cfa, "bilinear")
    return guide, guide + PERIOD * torch.round((smooth - guide) / PERIOD)


def radiance_power(radiance: torch.Tensor, gamma: float) -> torch.Tensor:
    """``radiance ** gamma`` (negatives clamped to 0): another scene's dynamic range, ``gamma`` times the stops, with
    the same multiplicative structure (``(R L) ** gamma = R ** gamma L ** gamma``: textures under shading stay
    textures under shading). The exposure that follows fixes the scale."""
    return radiance.clamp_min(0.0) ** gamma


def make_batch(
    scenes: list[torch.Tensor],
    batch: int,
    size: int,
    rng: np.random.Generator,
    args: argparse.Namespace,
    references: list[dict[bool, dict[float, float]]] | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(batch, 3, size, size) wrapped inputs and the true counts they come from.

    Grey samples are repeated into the three channels. A share ``args.scene_exposure`` of the scene crops is exposed
    by their whole scene's percentile (``references``: :func:`exposure_references` of every scene); the others are
    raised to a power log-uniform in ``[1 / args.gamma, args.gamma]`` (:func:`radiance_power`) when ``args.gamma >
    1``. A share ``args.mosaic`` of the samples is mosaicked with a random Bayer pattern first (:func:`mosaic_pair`).
    """
    wrapped, truth = [], []
    for _ in range(batch):
        scene = None
        if rng.random() < args.procedural:
            radiance = procedural_scene(size, rng)
        else:
            radiance, index = random_crop(scenes, size, rng, tuple(args.scales), with_index=True)
            if args.scene_exposure > 0 and rng.random() < args.scene_exposure:  # no draw when off: runs reproduce
                scene = references[index]
            if args.gamma > 1 and scene is None:  # no draw when off either (nor by a whole scene's exposure)
                radiance = radiance_power(radiance, math.exp(rng.uniform(-math.log(args.gamma), math.log(args.gamma))))
        counts = capture_pair(radiance, rng, args.noise, scene).double()
        counts = counts.expand(3, -1, -1) if counts.shape[0] == 1 else counts
        if rng.random() < args.mosaic:
            guide, counts = mosaic_pair(counts, str(rng.choice(CFA_PATTERNS)))
        else:
            guide = modulo_wrap(counts, BITS)
        wrapped.append(guide)
        truth.append(counts)
    return torch.stack(wrapped).float(), torch.stack(truth).float()


class Batches(torch.utils.data.IterableDataset):
    """Endless :func:`make_batch` batches for a DataLoader with worker processes (``--workers``): each worker draws
    from its own generator, seeded by ``(seed, worker id)``, so a run is repeatable for a given number of workers."""

    def __init__(
        self, scenes: list[torch.Tensor], args: argparse.Namespace, references: list[dict[bool, dict[float, float]]]
    ) -> None:
        self.scenes, self.args, self.references = scenes, args, references

    def __iter__(self) -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
        info = torch.utils.data.get_worker_info()
        torch.set_num_threads(1)  # many workers, one core each
        rng = np.random.default_rng([self.args.seed, 0 if info is None else info.id + 1])
        while True:
            yield make_batch(self.scenes, self.args.batch, self.args.crop, rng, self.args, self.references)


def train(args: argparse.Namespace) -> dict[str, object]:
    if args.mosaic > 0 and args.crop % 2:
        raise SystemExit(f"--mosaic needs an even --crop (whole 2 x 2 cells); got {args.crop}")
    if not args.gamma >= 1:  # [1/G, G] is the range: G below 1 would silently mean no power at all
        raise SystemExit(f"--gamma must be >= 1 (1: off; G gives powers in [1/G, G]); got {args.gamma}")
    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    rng = np.random.default_rng(args.seed)
    scenes = load_train_scenes(args.scene_side, args.data)
    if not scenes:
        raise SystemExit(f"no training scenes under {args.data} (its polyhaven-cc0 and openexr-images folders)")
    print(f"loaded {len(scenes)} training scenes", flush=True)
    references = [exposure_references(s) for s in scenes] if args.scene_exposure > 0 else []
    net = EdgeJumpNet(
        width=args.width, max_jump=args.max_jump, dilations=tuple(args.dilations), coarse=tuple(args.coarse)
    )
    if args.init is not None:  # fine-tune: start from earlier weights (same width and max_jump)
        record = torch.load(args.init, map_location="cpu", weights_only=True)
        state = {k: v.float() for k, v in record["state"].items()}
        # Bottleneck blocks the earlier network lacks (more --dilations) start near zero: their residual adds
        # almost nothing, so the network starts as the earlier one and the new blocks still get gradients. A new
        # 1/8 level (--coarse) keeps its default initialisation but its merge into the bottleneck (up4) starts
        # near zero, for the same reason.
        new = [k for k in net.state_dict() if k not in state]
        if any(not k.startswith(("mid.", "enc4.", "deep.", "up4.")) for k in new):
            raise SystemExit(f"--init {args.init} does not match this network: missing {new}")
        dropped = [k for k in state if k not in net.state_dict()]
        if dropped:  # e.g. a 1/8 level the command line left out (--coarse)
            raise SystemExit(f"--init {args.init} has parameters this network lacks: {dropped}")
        net.load_state_dict(state, strict=False)
        with torch.no_grad():
            for k in new:
                if k.startswith(("mid.", "up4.")):
                    net.state_dict()[k].mul_(0.01)
        print(f"starting from {args.init}" + (f" (new: {new})" if new else ""), flush=True)
    if args.crop % net.stride:
        raise SystemExit(f"--crop must be a multiple of {net.stride} for this network; got {args.crop}")
    n_params = sum(p.numel() for p in net.parameters())
    print(f"parameters: {n_params}", flush=True)
    device = torch.device(args.device)
    net.to(device)
    opt = torch.optim.Adam(net.parameters(), lr=args.lr)
    steps = args.steps
    start = time.perf_counter()
    step, smooth, hard_acc = 0, None, None
    loader = None
    if args.workers:  # batches made in worker processes while the network trains (for a GPU; a different stream)
        data = torch.utils.data.DataLoader(
            Batches(scenes, args, references), batch_size=None, num_workers=args.workers, prefetch_factor=4
        )
        loader = iter(data)
    while steps == 0 or step < steps:
        if steps == 0 and step == args.probe_steps:
            per_step = (time.perf_counter() - start) / step
            steps = max(step + 1, int(args.minutes * 60 / per_step))
            print(f"{per_step:.2f} s/step: training {steps} steps", flush=True)
        total = steps or max(args.probe_steps * 100, 1)
        lr = args.lr * 0.5 * (1 + math.cos(math.pi * min(step / total, 1.0)))
        for group in opt.param_groups:
            group["lr"] = lr
        batch = next(loader) if loader is not None else make_batch(scenes, args.batch, args.crop, rng, args, references)
        wrapped, counts = (t.to(device) for t in batch)
        target, hard = edge_targets(counts, BITS, args.max_jump)
        logits = net(edge_features(wrapped, BITS))
        loss = edge_loss(logits, target, args.hard_weight)
        opt.zero_grad()
        loss.backward()
        opt.step()
        with torch.no_grad():
            right = logits.argmax(dim=3) == target
            acc = float(right[hard].float().mean()) if hard.any() else math.nan
        loss = loss.detach()
        smooth = float(loss) if smooth is None else 0.98 * smooth + 0.02 * float(loss)
        if not math.isnan(acc):
            hard_acc = acc if hard_acc is None else 0.98 * hard_acc + 0.02 * acc
        step += 1
        if step % args.log_every == 0:
            print(
                f"step {step}/{steps} loss {smooth:.4f} hard-pair acc {hard_acc or 0:.3f} lr {lr:.2e} "
                f"{time.perf_counter() - start:.0f}s",
                flush=True,
            )
    minutes = (time.perf_counter() - start) / 60
    record = {"config": net.config, "state": {k: v.detach().cpu().half() for k, v in net.state_dict().items()}}
    args.out.mkdir(parents=True, exist_ok=True)
    torch.save(record, args.out / "edge_jump.pt")
    summary = {
        "steps": step,
        "minutes": round(minutes, 1),
        "parameters": n_params,
        "final_loss": smooth,
        "hard_pair_accuracy": hard_acc,
        "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
    }
    (args.out / "train_summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps(summary), flush=True)
    return summary


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("torch_modulo/singleshot/weights"))
    ap.add_argument("--steps", type=int, default=0, help="training steps (0: as many as fit in --minutes)")
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--probe-steps", type=int, default=20, help="steps timed to size --minutes")
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--crop", type=int, default=96)
    ap.add_argument("--width", type=int, default=16)
    ap.add_argument("--max-jump", type=int, default=15)
    ap.add_argument("--dilations", type=int, nargs="+", default=[1, 2, 4, 8], help="bottleneck dilations")
    ap.add_argument(
        "--coarse", type=int, nargs="*", default=[], help="dilations of residual blocks at 1/8 (none: no such level)"
    )
    ap.add_argument("--lr", type=float, default=2e-3)
    ap.add_argument("--hard-weight", type=float, default=5.0)
    ap.add_argument("--procedural", type=float, default=0.3, help="share of procedural crops")
    ap.add_argument("--noise", type=float, default=0.15, help="share of crops with sensor noise")
    ap.add_argument("--mosaic", type=float, default=0.0, help="share of crops seen as Bayer mosaics")
    ap.add_argument(
        "--scene-exposure", type=float, default=0.0, help="share of scene crops exposed by the whole scene's percentile"
    )
    ap.add_argument(
        "--gamma",
        type=float,
        default=1.0,
        help="scene crops' radiance raised to a power log-uniform in [1 / GAMMA, GAMMA] (>= 1; 1: off)",
    )
    ap.add_argument("--scene-side", type=int, default=1024, help="scenes are loaded at this longer side")
    ap.add_argument(
        "--data",
        type=Path,
        default=protocols.DEV_SCENES,
        help="scenes folder; only its polyhaven-cc0 and openexr-images folders are read (default: the dev scenes)",
    )
    ap.add_argument(
        "--scales", type=int, nargs="+", default=[1, 2, 2], help="area-averaging factors crops are drawn from"
    )
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--workers", type=int, default=0, help="processes making batches (0: in the training loop)")
    ap.add_argument(
        "--device", default="cpu", help="where the network trains (cuda on a GPU); batches are made on the CPU"
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--init", type=Path, default=None, help="start from these weights (fine-tuning)")
    ap.add_argument("--log-every", type=int, default=25)
    return ap.parse_args(argv)


if __name__ == "__main__":
    train(parse_args())
