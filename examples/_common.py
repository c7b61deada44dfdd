"""Helpers shared by the figure scripts in examples/: scenes, the benchmark protocols, figure output, verdicts.

Not part of the library: the scripts import it as ``_common`` (they run with examples/ on ``sys.path``).
"""

from __future__ import annotations

import argparse
import io
import math
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
import torch.nn.functional as F  # noqa: E402
from PIL import Image  # noqa: E402

from torch_modulo.assets import default_scene_path  # noqa: E402
from torch_modulo.io import read_image  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: The real HDR scenes beside the project (never copied into it); see its README.
SHARED_HDR = ROOT.parent / "shared" / "data" / "hdr"
DEFAULT_OUT = ROOT / "examples" / "out"
#: Luminance weights of linear Rec.709 primaries (BENCHMARKS.md protocol A).
LUMA = (0.2126, 0.7152, 0.0722)
#: Largest PNG the docs embed.
MAX_PNG_BYTES = 400 * 1024


def parser(description: str) -> argparse.ArgumentParser:
    """The arguments every figure script takes: --out (a folder) and --quick (reduced size, for tests)."""
    p = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"folder for the PNG (default {DEFAULT_OUT})")
    p.add_argument("--quick", action="store_true", help="reduced size (what the tests run)")
    return p


# --------------------------------------------------------------------------------------------------------------------
# scenes
# --------------------------------------------------------------------------------------------------------------------


def scene_path(name: str) -> Path:
    """A scene by its path under ../shared/data/hdr ("hdr-samples/memorial.hdr"); the embedded CC0 scene
    (Poly Haven "apartment") when the shared folder is absent or the name is "embedded"."""
    if name == "embedded":
        return default_scene_path()
    path = SHARED_HDR / name
    if path.is_file():
        return path
    if not SHARED_HDR.is_dir():
        return default_scene_path()
    raise FileNotFoundError(f"scene {name!r} not found under {SHARED_HDR}")


def shared_available() -> bool:
    return SHARED_HDR.is_dir()


def load_scene(path: str | os.PathLike[str], max_side: int = 512) -> torch.Tensor:
    """A radiance map as (1, 3, H, W) float64 >= 0, downsampled by whole-pixel area averaging (BENCHMARKS.md)
    until its longer side is at most ``max_side``. NaN and negative values become 0; a grey file (with or without
    alpha) gives three equal channels, and only the first three channels of others are kept."""
    image = read_image(path, dtype=torch.float64)
    assert isinstance(image, torch.Tensor)
    image = torch.nan_to_num(image, nan=0.0, posinf=0.0, neginf=0.0).clamp_(min=0.0)
    image = image[:1].expand(3, -1, -1) if image.shape[0] < 3 else image[:3]  # grey (+ alpha): first channel
    x = image[None].contiguous()
    h, w = x.shape[-2:]
    factor = max(1, math.ceil(max(h, w) / max_side))
    if factor > 1:
        x = F.avg_pool2d(x[..., : h - h % factor, : w - w % factor], factor)
    return x


def luminance(rgb: torch.Tensor) -> torch.Tensor:
    """Y = 0.2126 R + 0.7152 G + 0.0722 B of a (B, 3, H, W) tensor, as (B, 1, H, W)."""
    w = torch.tensor(LUMA, dtype=rgb.dtype, device=rgb.device).view(1, 3, 1, 1)
    return (rgb * w).sum(dim=1, keepdim=True)


def protocol_a(hdr: torch.Tensor, in_bits: int = 12) -> torch.Tensor:
    """BENCHMARKS.md protocol A: luminance scaled so that its 99.9th percentile is 2^in_bits - 1, clipped, floored.

    Returns the true counts I, (1, 1, H, W) float64; the modulus image is ``I mod 2^N``.
    """
    y = luminance(hdr)
    top = float(2**in_bits - 1)
    p = float(torch.quantile(y.flatten().float(), 0.999))
    scale = top / p if p > 0 else 1.0
    return torch.floor((y * scale).clamp(0.0, top))


def stops(x: torch.Tensor) -> float:
    """Dynamic range log2(p99.9 / p0.1) of the positive values of ``x``, in stops (the data README's measure)."""
    v = x[x > 0].flatten().double()
    if v.numel() == 0:
        return 0.0
    hi, lo = torch.quantile(v, torch.tensor([0.999, 0.001], dtype=v.dtype))
    return math.log2(float(hi) / float(lo))


# --------------------------------------------------------------------------------------------------------------------
# display
# --------------------------------------------------------------------------------------------------------------------


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """sRGB transfer function of linear display values in [0, 1]."""
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def as_rgb(x: torch.Tensor) -> np.ndarray:
    """(1, C, H, W) or (C, H, W) display values in [0, 1] to an (H, W, 3) array for imshow."""
    if x.dim() == 4:
        x = x[0]
    a = x.detach().cpu().double().numpy()
    a = np.repeat(a, 3, axis=0) if a.shape[0] == 1 else a[:3]
    return np.clip(np.transpose(a, (1, 2, 0)), 0.0, 1.0)


def show(ax: plt.Axes, image: np.ndarray | torch.Tensor, title: str, **kwargs: object) -> None:
    """imshow without axes; 2-D arrays in grey unless a cmap is given."""
    if isinstance(image, torch.Tensor):
        image = as_rgb(image)
    if image.ndim == 2:
        kwargs.setdefault("cmap", "gray")
    ax.imshow(image, interpolation="nearest", **kwargs)
    ax.set_title(title, fontsize=8)
    ax.set_axis_off()


def save_figure(fig: plt.Figure, path: Path, max_bytes: int = MAX_PNG_BYTES) -> Path:
    """Write a matplotlib figure as PNG atomically (temporary file in the same folder, then os.replace).

    The PNG is written as RGB; if it exceeds ``max_bytes`` it is reduced to a 256-colour palette.
    """
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    plt.close(fig)
    buffer.seek(0)
    image = Image.open(buffer).convert("RGB")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}", suffix=".tmp")
    os.close(fd)
    try:
        image.save(tmp, format="PNG", optimize=True)
        if os.path.getsize(tmp) > max_bytes:
            image.quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(tmp, format="PNG", optimize=True)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; give the PNG the usual permissions
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB)")
    return path


def verdict(holds: bool | str, claim: str, detail: str) -> str:
    """Print and return the one-line verdict every script ends with; ``holds`` is a bool or "PARTLY"."""
    status = holds if isinstance(holds, str) else ("HOLDS" if holds else "DOES NOT HOLD")
    line = f"VERDICT: {status} - {claim}: {detail}"
    print(line)
    return line


def table(rows: Sequence[Sequence[object]], header: Sequence[str]) -> None:
    """Print a plain fixed-width table."""
    cells = [[str(c) for c in header]] + [[f"{c:.4g}" if isinstance(c, float) else str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    for j, r in enumerate(cells):
        print("  ".join(c.rjust(w) for c, w in zip(r, widths, strict=True)))
        if j == 0:
            print("  ".join("-" * w for w in widths))
