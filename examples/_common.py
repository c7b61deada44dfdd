"""Helpers shared by the figure scripts in examples/: finding scenes, figure output, tables and verdicts.

Not part of the library: the scripts import it as ``_common`` (they run with examples/ on ``sys.path``). Loading
scenes, the benchmark protocols and the scores come from :mod:`torch_modulo.protocols`, as in the benchmarks.
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
from PIL import Image  # noqa: E402

from torch_modulo import protocols  # noqa: E402
from torch_modulo.assets import default_scene_path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: The real HDR scenes beside the project (never copied into it); the tests point it elsewhere.
SCENES_DIR = protocols.DEV_SCENES
DEFAULT_OUT = ROOT / "examples" / "out"
#: The name that asks for the scene embedded in the package.
EMBEDDED = "embedded"
#: The embedded scene's label in tables and titles.
EMBEDDED_LABEL = "apartment (embedded)"
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


def find_scenes(names: Sequence[str], *, required: bool = False, fallback: bool = True) -> list[tuple[str, Path]]:
    """``(label, path)`` of the scenes of ``names`` that exist, each under its own name; the missing ones are printed.

    Names are paths under :data:`SCENES_DIR` ("hdr-samples/memorial.hdr") or "embedded" (the CC0 scene shipped in
    the package, Poly Haven "apartment"). A scene that is absent (a fresh clone has no scenes folder) is never
    replaced under its name.

    Args:
        names: the scenes a script wants.
        required: the user named them: a missing scene is an error.
        fallback: when none of them exists, use the embedded scene instead (under its own label).

    Raises:
        FileNotFoundError: ``required`` and a scene is missing.
    """
    found, missing = [], []
    for name in names:
        if name == EMBEDDED:
            found.append((EMBEDDED_LABEL, default_scene_path()))
        elif (SCENES_DIR / name).is_file():
            found.append((Path(name).stem, SCENES_DIR / name))
        else:
            missing.append(name)
    if missing and required:
        raise FileNotFoundError(f"scene(s) not found under {SCENES_DIR}: {', '.join(missing)}")
    if missing:
        where = f"under {SCENES_DIR}" if SCENES_DIR.is_dir() else f"({SCENES_DIR} does not exist)"
        print(f"missing {len(missing)} of {len(names)} scene(s) {where}: {', '.join(missing)}")
        if not found and fallback:
            print(f"using the embedded scene instead: {EMBEDDED_LABEL}")
            found.append((EMBEDDED_LABEL, default_scene_path()))
    return found


def stops(x: torch.Tensor) -> float:
    """Dynamic range log2(p99.9 / p0.1) of the positive values of ``x``, in stops."""
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
