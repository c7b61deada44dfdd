"""Fig. 2 of the paper: a smooth 10-bit surface wrapped to 8 bits and unwrapped from that single modulus image.

    python examples/fig02_wrap_unwrap.py                 # writes examples/out/fig02_wrap_unwrap.png
    python examples/fig02_wrap_unwrap.py --quick --out /tmp/figs

Paper (Sec. 3, Fig. 2): "An over-simplified wrapping and unwrapping example: a surface with contrast ratio
1023 : 1 is wrapped to an 8-bit range of a contrast ratio 255 : 1; note the modulo fringes in the wrapped image."

Here the surface is a sum of Gaussian bumps (MATLAB's ``peaks`` shape) scaled to integer counts 1 .. 1023, wrapped
by :func:`torch_modulo.modulo_wrap` (Eq. 1) and unwrapped by :func:`torch_modulo.unwrap_single` with the paper's
graph cut (Eqs. 3-5). Score: exact-k share and whether the restored surface equals the original.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch
from _common import parser, save_figure, show, verdict
from matplotlib import pyplot as plt

from torch_modulo import exact_k_share, modulo_wrap
from torch_modulo.singleshot import unwrap_single

BITS = 8
TOP = 1023.0


def surface(size: int) -> torch.Tensor:
    """MATLAB's ``peaks`` on a ``size`` x ``size`` grid, scaled to integer counts in [1, 1023], (1, 1, H, W)."""
    t = torch.linspace(-3.0, 3.0, size, dtype=torch.float64)
    y, x = torch.meshgrid(t, t, indexing="ij")
    z = (
        3 * (1 - x) ** 2 * torch.exp(-(x**2) - (y + 1) ** 2)
        - 10 * (x / 5 - x**3 - y**5) * torch.exp(-(x**2) - y**2)
        - torch.exp(-((x + 1) ** 2) - y**2) / 3
    )
    z = (z - z.min()) / (z.max() - z.min())
    return torch.round(1 + z * (TOP - 1)).view(1, 1, size, size)


def _surface_plot(ax: plt.Axes, z: np.ndarray, title: str, zmax: float) -> None:
    h, w = z.shape
    yy, xx = np.mgrid[0:h, 0:w]
    step = max(1, h // 48)
    ax.plot_surface(
        xx[::step, ::step],
        yy[::step, ::step],
        z[::step, ::step],
        cmap="viridis",
        linewidth=0,
        antialiased=False,
        vmin=0,
        vmax=zmax,
    )
    ax.set_zlim(0, zmax)
    ax.set_title(title, fontsize=8)
    ax.tick_params(labelsize=6)
    ax.view_init(elev=35, azim=-60)


def main(argv: list[str] | None = None) -> dict[str, object]:
    args = parser(__doc__.split("\n\n")[0]).parse_args(argv)
    size = 64 if args.quick else 256
    truth = surface(size)
    modulus = modulo_wrap(truth, bits=BITS)
    start = time.perf_counter()
    restored = unwrap_single(modulus, bits=BITS, method="fast")
    seconds = time.perf_counter() - start
    share = float(exact_k_share(restored, truth, BITS)[0])
    equal = bool(torch.equal(restored, truth))
    fringes = int(torch.unique(torch.div(truth, 2**BITS, rounding_mode="floor")).numel())
    print(
        f"Fig. 2: {size}x{size} surface, counts {int(truth.min())}..{int(truth.max())} (contrast "
        f"{truth.max() / truth.min():.0f}:1), wrapped to {BITS} bits ({fringes} rollover levels)"
    )
    print(f"  unwrap_single: {seconds:.2f} s, exact-k {100 * share:.2f}%, restored == original: {equal}")

    fig = plt.figure(figsize=(11.0, 6.4), dpi=90)
    panels = [
        (truth, f"original: 10 bits, contrast {TOP:.0f}:1", TOP),
        (modulus, f"wrapped to {BITS} bits (Eq. 1): modulo fringes", 2.0**BITS - 1),
        (restored, f"unwrapped (graph cut): {'exact' if equal else f'{100 * share:.1f}% exact-k'}", TOP),
    ]
    for j, (z, title, zmax) in enumerate(panels):
        _surface_plot(fig.add_subplot(2, 3, j + 1, projection="3d"), z[0, 0].numpy(), title, zmax)
        show(fig.add_subplot(2, 3, j + 4), z[0, 0].numpy(), "", cmap="viridis", vmin=0, vmax=zmax)
    fig.suptitle("Fig. 2: wrapping a 10-bit surface to 8 bits and unwrapping it", fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    path = save_figure(fig, Path(args.out) / "fig02_wrap_unwrap.png")
    line = verdict(
        equal,
        "a smooth 10-bit surface is recovered from its 8-bit modulus",
        f"exact-k {100 * share:.2f}%, identical: {equal}, {seconds:.2f} s",
    )
    return {"exact_k": share, "equal": equal, "seconds": seconds, "holds": equal, "png": path, "verdict": line}


if __name__ == "__main__":
    main()
