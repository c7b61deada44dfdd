"""Research harness for single-shot unwrapping on real HDR scenes: the natural-image model against baselines.

Builds protocols A and B (:mod:`torch_modulo.protocols`) from every scene under ``--data`` (all folders), runs one
or more unwrapping methods (``natural``: :mod:`research.natural`; ``qg``: path following per channel; ``paper``;
``skimage``) and prints exact-k, PSNR (peak 4095, offsets not aligned) and seconds per megapixel per channel per
scene, then a summary and a JSON line.

Examples (from the repository root):
    python -m research.harness --methods natural --protocols A B
    python -m research.harness --methods paper natural skimage --max-scenes 6 --split tune
    python -m research.harness --methods natural --opt potential=linear --energy-check

Splits: scenes are sorted by path; ``--split tune`` keeps the even-indexed ones, ``--split held`` the odd ones,
``all`` (default) every scene. Tuning was done on ``tune`` only.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

from research.common import DATA
from torch_modulo import protocols
from torch_modulo._argtypes import nonnegative_int, positive_int

CACHE = Path(os.environ.get("TM_RESEARCH_CACHE", "/tmp/tm_research_cache"))


def list_scenes(data: Path) -> list[Path]:
    return protocols.list_scenes(data)


def load_scene(path: Path, longest: int = 512) -> np.ndarray:
    """(3, H, W) float64 radiance (grey files repeated), cached as .npy under CACHE."""
    CACHE.mkdir(parents=True, exist_ok=True)
    key = CACHE / f"{path.parent.name}__{path.stem}__{longest}.npy"
    if key.exists():
        return np.load(key)
    img = protocols.load_scene(path, longest).expand(3, -1, -1).numpy()
    tmp = key.with_suffix(".tmp.npy")
    np.save(tmp, img)
    os.replace(tmp, key)
    return img


def protocol_a(rgb: np.ndarray) -> np.ndarray:
    return protocols.protocol_a(torch.from_numpy(rgb)).numpy()


def protocol_b(rgb: np.ndarray, share: float = 0.2) -> np.ndarray:
    return protocols.protocol_b(torch.from_numpy(rgb), share=share).numpy()


# ------------------------------------------------------------------------------------------------- methods


def run_method(name: str, modulus: np.ndarray, bits: int, opts: dict) -> tuple[np.ndarray, dict]:
    if name == "natural":
        from research.natural import unwrap_natural

        return unwrap_natural(modulus, bits, **opts)
    if name == "skimage":
        from skimage.restoration import unwrap_phase

        period = 1 << bits
        out = np.empty_like(modulus)
        for c in range(modulus.shape[0]):
            ph = modulus[c] * (2 * np.pi / period) - np.pi
            un = unwrap_phase(ph)
            restored = (un + np.pi) * period / (2 * np.pi)
            k = np.round((restored - modulus[c]) / period)
            k -= k.min()
            out[c] = modulus[c] + period * k
        return out, {}
    if name == "qg":
        from torch_modulo.singleshot.anchor import anchor_k
        from torch_modulo.singleshot.pathfollow import quality_guided_k

        period = 1 << bits
        out = np.empty_like(modulus)
        for c in range(modulus.shape[0]):
            k = anchor_k(quality_guided_k(modulus[c], bits))
            out[c] = modulus[c] + period * k
        return out, {}
    if name == "paper":
        import torch_modulo.singleshot as ss

        t = torch.from_numpy(modulus)
        return ss.unwrap_single(t, bits=bits, method="paper", **opts).numpy(), {}
    raise ValueError(f"unknown method {name!r}")


def score(restored: np.ndarray, truth: np.ndarray, bits: int) -> tuple[float, float]:
    from torch_modulo.metrics import exact_k_share, psnr

    r = torch.from_numpy(np.asarray(restored, dtype=np.float64))
    t = torch.from_numpy(truth)
    return float(exact_k_share(r, t, bits)[0]), float(psnr(r, t, 4095.0)[0])


def parse_opts(items: list[str]) -> dict:
    out = {}
    for item in items:
        k, v = item.split("=", 1)
        if "," in v:
            out[k] = tuple(float(x) for x in v.split(",") if x)
            continue
        for conv in (int, float):
            try:
                v = conv(v)
                break
            except ValueError:
                pass
        else:
            if v in ("True", "False"):
                v = v == "True"
        out[k] = v
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--methods", nargs="+", default=["natural"])
    ap.add_argument("--protocols", nargs="+", default=["A", "B"], choices=["A", "B"])
    ap.add_argument("--max-scenes", type=nonnegative_int, default=0)
    ap.add_argument("--scale", type=positive_int, default=512, help="longest side after downsampling")
    ap.add_argument("--split", choices=["all", "tune", "held"], default="all")
    ap.add_argument("--only", nargs="*", default=[], help="substrings of scene names to keep")
    ap.add_argument("--opt", nargs="*", default=[], help="key=value options for the natural method")
    ap.add_argument("--energy-check", action="store_true", help="print the natural energy of truth vs result")
    ap.add_argument("--json", type=Path, default=None, help="write per-scene rows here")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    scenes = list_scenes(args.data)
    if args.split == "tune":
        scenes = scenes[0::2]
    elif args.split == "held":
        scenes = scenes[1::2]
    if args.only:
        scenes = [s for s in scenes if any(o in s.stem for o in args.only)]
    if args.max_scenes:
        scenes = scenes[: args.max_scenes]
    opts = parse_opts(args.opt)
    bits = 8
    rows = []
    for path in scenes:
        rgb = load_scene(path, args.scale)
        for proto in args.protocols:
            truth = protocol_a(rgb) if proto == "A" else protocol_b(rgb)
            modulus = np.mod(truth, 1 << bits)
            mp = truth.shape[1] * truth.shape[2] / 1e6
            for method in args.methods:
                t0 = time.perf_counter()
                o = dict(opts) if method in ("natural",) else {}
                if method == "natural" and proto == "A":
                    o.setdefault("max_count", 4095)
                elif method == "natural":
                    o.setdefault("max_count", 4095)
                restored, info = run_method(method, modulus, bits, o)
                sec = time.perf_counter() - t0
                ek, ps = score(restored, truth, bits)
                row = dict(
                    scene=path.stem,
                    proto=proto,
                    method=method,
                    exact_k=ek,
                    psnr=ps,
                    s_per_mp_ch=sec / mp / truth.shape[0],
                    sec=sec,
                )
                if args.energy_check and method == "natural":
                    from research.natural import natural_energy

                    eo = {k: v for k, v in o.items() if k != "return_confidence"}
                    row["e_truth"] = natural_energy(truth, bits, **eo)
                    row["e_found"] = natural_energy(np.asarray(restored).reshape(truth.shape), bits, **eo)
                    row["e_init"] = info.get("energy_init", float("nan"))
                    print(f"   energy init={row['e_init']:.1f} found={row['e_found']:.1f} truth={row['e_truth']:.1f}")
                rows.append(row)
                print(
                    f"{proto} {method:8s} {path.stem[:28]:28s} k={ek:.4f} psnr={ps:6.2f} "
                    f"{row['s_per_mp_ch']:6.2f} s/MP/ch",
                    flush=True,
                )
    print()
    summary = {}
    for proto in args.protocols:
        for method in args.methods:
            sel = [r for r in rows if r["proto"] == proto and r["method"] == method]
            if not sel:
                continue
            ps = [min(r["psnr"], 100.0) for r in sel]
            s = dict(
                n=len(sel),
                mean_exact_k=float(np.mean([r["exact_k"] for r in sel])),
                mean_psnr=float(np.mean(ps)),
                median_psnr=float(np.median(ps)),
                perfect=sum(r["exact_k"] == 1.0 for r in sel),
                median_s_per_mp_ch=float(np.median([r["s_per_mp_ch"] for r in sel])),
            )
            summary[f"{proto}/{method}"] = s
            print(
                f"{proto} {method:8s} n={s['n']} exact-k={s['mean_exact_k']:.4f} psnr(mean, inf->100)="
                f"{s['mean_psnr']:.2f} median={s['median_psnr']:.2f} perfect={s['perfect']} "
                f"{s['median_s_per_mp_ch']:.2f} s/MP/ch"
            )
    print(json.dumps(dict(summary=summary, options=opts, split=args.split)))
    if args.json:
        tmp = args.json.with_suffix(".tmp")
        tmp.write_text(json.dumps(rows, indent=1))
        os.replace(tmp, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
