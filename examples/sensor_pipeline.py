"""From a folder of EXR scenes, or a folder of camera frames, to unwrapped radiance with the same few lines.

    python examples/sensor_pipeline.py                        # the bundled CC0 scene, simulated 8-bit camera
    python examples/sensor_pipeline.py --scenes DIR           # every EXR/HDR scene in DIR
    python examples/sensor_pipeline.py --frames DIR           # frames of a real modulo camera (see FileSensor);
                                                              # mosaics are demosaicked, every scene is written
    python examples/sensor_pipeline.py --noise none           # noise-free sensor: every rollover count exact

For scenes, a simulated digital-pixel modulo sensor (shot noise, 1 e- read noise) captures each scene at planned
exposures; the frames are written to OUT/frames/<scene>/ exactly as a camera folder would look (PNG + frames.json)
and read back through FileSensor, so the unwrapping code below is the same for simulated and real frames. A
conventional 8-bit sensor with the same noise, seed and exposures is merged Debevec-style for comparison. Writes
OUT/<scene>_radiance.exr and OUT/<scene>_tonemapped.png and prints one line per scene.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import torch

from torch_modulo.assets import default_scene_path
from torch_modulo.cfa import demosaic
from torch_modulo.data import HDRFolder
from torch_modulo.io import write_image
from torch_modulo.metrics import exact_k_share
from torch_modulo.multishot import merge_intensity, plan_exposures, unwrap_multi
from torch_modulo.sensors import (
    FileSensor,
    FrameStack,
    NoiseModel,
    SimulatedIntensitySensor,
    SimulatedModuloSensor,
    write_frames,
)
from torch_modulo.tonemap import tonemap_reinhard


def unwrap(stack: FrameStack) -> torch.Tensor:
    """The downstream code: it does not care where the frames came from."""
    if stack.kind == "intensity":
        return merge_intensity(stack.frames, stack.exposures, stack.bits)
    return unwrap_multi(stack.moduli, stack.exposures, stack.bits)


def save(radiance: torch.Tensor, out: Path, name: str, metadata: dict) -> None:
    write_image(out / f"{name}_radiance.exr", radiance[0].float(), metadata)
    display = tonemap_reinhard(radiance.float(), srgb=True)
    write_image(out / f"{name}_tonemapped.png", display[0], dtype="uint8", normalized=True)


def relative_errors(estimate: torch.Tensor, truth: torch.Tensor, floor: float) -> torch.Tensor:
    mask = truth > floor
    return ((estimate - truth).abs() / truth)[mask]


def from_scenes(args: argparse.Namespace) -> None:
    noise = None if args.noise == "none" else NoiseModel()
    scenes = HDRFolder(args.scenes, resize=args.size, return_path=True, dtype=torch.float64)
    for index in range(min(len(scenes), args.max_scenes)):
        scene, path = scenes[index]
        name = Path(path).stem
        # Radiance in counts per unit exposure: the brightest pixel just fits the shortest exposure (no rollover).
        radiance = (scene * ((2**args.bits - 1) / float(scene.max())))[None]
        luma = radiance.mean(1).flatten()
        dark = float(luma[luma > 0].kthvalue(max(1, int(0.001 * int((luma > 0).sum())))).values)
        stops = math.log2((2**args.bits - 1) / dark) + args.bits  # reach ~2^bits counts at the darkest 0.1 %
        exposures = plan_exposures(stops, args.bits, max_ratio=args.max_ratio)

        stack = SimulatedModuloSensor(args.bits, noise, seed=index)(radiance, exposures)
        folder = write_frames(stack, args.out / "frames" / name, format="png").parent
        camera = FileSensor(folder).read()  # what a real camera folder gives
        assert camera == stack.to(dtype=camera.dtype)

        hdr = unwrap(camera)
        clipped = SimulatedIntensitySensor(args.bits, noise, seed=index)(radiance, exposures)
        merged = unwrap(clipped)

        # What unwrapping had to find: the counts the same noisy sensor would read with an unbounded counter.
        unbounded = SimulatedIntensitySensor(24, noise, seed=index)(radiance, exposures).frames[:, -1]
        restored_counts = unwrap_multi(camera.moduli, camera.exposures, camera.bits, return_counts=True)
        restored_counts = restored_counts.clamp_min(0)  # noise can push a dark pixel's count below zero
        exact_k = float(exact_k_share(restored_counts, unbounded.to(restored_counts.dtype), args.bits, align=False)[0])
        floor = 16.0 / exposures[-1]  # pixels with at least 16 counts at the longest exposure
        errors = {
            "modulo": relative_errors(hdr.to(radiance.dtype), radiance, floor),
            "unbounded": relative_errors(unbounded.to(radiance.dtype) / exposures[-1], radiance, floor),
            "intensity merge": relative_errors(merged.to(radiance.dtype), radiance, floor),
        }
        save(hdr, args.out, name, {"source": str(path), "bits": args.bits, "exposures": exposures})
        summary = ", ".join(
            f"{key} {float(e.median()):.2e} / {float(e.quantile(0.99)):.2e}" for key, e in errors.items()
        )
        print(
            f"{name}: {radiance.shape[-1]}x{radiance.shape[-2]}, {stops:.1f} stops, {len(exposures)} exposures "
            f"{[round(t, 1) for t in exposures]}, noise {'on' if noise else 'off'} | exact k {100 * exact_k:.2f}% | "
            f"relative error (median / 99th percentile): {summary}"
        )


def from_frames(args: argparse.Namespace) -> None:
    stack = FileSensor(args.frames, bits=args.frame_bits).read()
    hdr = unwrap(stack)
    if stack.cfa is not None:  # a colour camera's mosaics: unwrapped counts first, then RGB
        hdr = demosaic(hdr, stack.cfa)
    name = Path(args.frames).name or "frames"
    for b in range(hdr.shape[0]):  # every scene of the stack
        scene = name if hdr.shape[0] == 1 else f"{name}_b{b:03d}"
        metadata = {"source": str(args.frames), "bits": stack.bits, "exposures": stack.exposure_matrix()[b].tolist()}
        save(hdr[b : b + 1], args.out, scene, metadata)
        peak = float(hdr[b].max())
        print(f"{scene}: {stack} -> radiance {tuple(hdr[b].shape)}, max {peak:.4g} counts per unit exposure")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--scenes",
        type=Path,
        default=default_scene_path().parent,
        help="folder of EXR/HDR scenes (default: the bundled CC0 scene)",
    )
    parser.add_argument("--frames", type=Path, default=None, help="folder of camera frames (FileSensor)")
    parser.add_argument("--frame-bits", type=int, default=None, help="bit depth of the camera frames if not stored")
    parser.add_argument("--out", type=Path, default=Path("out/sensor_pipeline"))
    parser.add_argument("--bits", type=int, default=8)
    parser.add_argument("--max-ratio", type=float, default=16.0, help="largest neighbouring exposure ratio")
    parser.add_argument("--noise", choices=["default", "none"], default="default")
    parser.add_argument("--size", type=int, default=512, help="longer side of the scenes after downsampling")
    parser.add_argument("--max-scenes", type=int, default=3)
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.frames is not None:
        from_frames(args)
    else:
        from_scenes(args)


if __name__ == "__main__":
    main()
