"""``unwrap_single`` and its layer twin :class:`SingleShotUnwrap`: the front end of every single-shot method.

It checks the input, turns a batch into planes, has them solved by the method of the registry
(:data:`~torch_modulo.singleshot.methods.REGISTRY`: on the input's device for the methods with a tensor solver,
else in worker processes, :mod:`torch_modulo.singleshot.workers`) and assembles the restored counts and a
:class:`SingleShotInfo`. A mosaic (``cfa=``) is interpolated on the circle first and solved as one colour image (or,
with ``"learned"``'s ``cells``, solved as two half-resolution colour images of its photosites; by default
``"learned"`` refines the guide's counts in those images).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Literal, overload

import numpy as np
import torch
from torch import nn

from torch_modulo._checks import (
    MAX_BITS,
    check_bits,
    check_flag,
    check_floating,
    check_has_values,
    check_image_shape,
    check_modulus,
    check_nonempty_image,
    check_tensor,
    like_memory_format,
)
from torch_modulo.cfa import cfa_colours, check_cfa, interpolate_wrapped, merge_planes, mosaic, split_planes
from torch_modulo.singleshot.learned.solver import mosaic_spec, refine_photosites, refines_photosites, solves_cells
from torch_modulo.singleshot.methods import REGISTRY, make_spec, solve_on_device
from torch_modulo.singleshot.spec import SolverSpec
from torch_modulo.singleshot.workers import check_workers, run_planes

__all__ = ["SingleShotInfo", "SingleShotUnwrap", "unwrap_single"]


@dataclass
class SingleShotInfo:
    """What the solver did, per image and channel (the data of the paper's Fig. 5b and 6).

    Everything is indexed ``[b][c]``; an unbatched (C, H, W) input counts as ``B = 1`` and an (H, W) input as
    ``B = C = 1``.

    Attributes:
        energies: ``energies[b][c]`` lists the energy (Eq. 3) before the first move and after every accepted
            move.
        iterations: (B, C) int64, accepted moves.
        cuts: (B, C) int64, minimum cuts solved (accepted or not).
        energy: (B, C) float64, the energy of the returned image (it can differ from the last entry of
            ``energies`` when anchoring clipped a few pixels below the darkest region to ``k = 0``; of a mosaic,
            that of its interpolated guide, before ``"learned"`` refines the photosites).
        seconds: (B, C) float64, wall time per plane.
        method: the method used.
        confidence: per-value confidence in ``(0, 1]`` from the same run, with the shape, dtype and device of the
            output, for the methods that give one (``"learned"``: the map of
            :func:`~torch_modulo.learned_confidence`, of the spanning tree before any ``max_cuts`` or ``levels``
            moves; of a mosaic, that of its interpolated guide at each photosite, before ``"learned"`` refines
            them), else None.
    """

    energies: list[list[list[float]]] = field(default_factory=list)
    iterations: torch.Tensor = field(default_factory=lambda: torch.zeros(0, 0, dtype=torch.int64))
    cuts: torch.Tensor = field(default_factory=lambda: torch.zeros(0, 0, dtype=torch.int64))
    energy: torch.Tensor = field(default_factory=lambda: torch.zeros(0, 0, dtype=torch.float64))
    seconds: torch.Tensor = field(default_factory=lambda: torch.zeros(0, 0, dtype=torch.float64))
    method: str = "learned"
    confidence: torch.Tensor | None = None


def _warn_inexact(restored: torch.Tensor, peak: float) -> None:
    """Warn when the restored counts (largest ``peak``) pass the integers ``restored``'s dtype holds exactly, with
    the advice that fits the dtype; float16 counts past its largest finite value (65504) became inf: say how many."""
    dtype = restored.dtype
    limit = 2 ** MAX_BITS.get(dtype, 53)  # every integer up to it, not all of those above
    if peak <= limit:
        return
    if dtype == torch.float64:
        advice = "they are rounded to the nearest float64, and no floating dtype holds them exactly"
    else:
        advice = "use float64 for exact counts" if dtype == torch.float32 else "use float32 or float64 for exact counts"
    warnings.warn(
        f"restored counts reach {peak:.0f}, beyond what {dtype} holds exactly ({limit}): {advice}", stacklevel=4
    )
    if dtype == torch.float16 and peak > float(torch.finfo(dtype).max):
        n_inf = int(torch.isinf(restored).sum())
        if n_inf:
            warnings.warn(
                f"{n_inf} restored counts are above 65504, the largest float16, and became inf; use float32 or float64",
                stacklevel=4,
            )


def _solve(modulus: torch.Tensor, spec: SolverSpec, workers: int | None) -> tuple[torch.Tensor, SingleShotInfo]:
    """Check the tensor, solve its planes (in workers when that pays) and assemble the output and the info."""
    check_tensor(modulus, "modulus")
    check_floating(modulus, "modulus")
    check_image_shape(modulus, "modulus", 2, 4)
    check_bits(spec.params.bits, modulus.dtype)
    check_nonempty_image(modulus, "modulus")
    h, w = modulus.shape[-2:]
    check_has_values(modulus, "modulus")  # the solvers read values, with the checks off too
    check_modulus(modulus, spec.params.bits)
    lead = (1, 1, *modulus.shape)[-4:-2]  # (B, C), with B = 1 and C = 1 filled in for unbatched inputs
    b, c = int(lead[0]), int(lead[1])
    batch = modulus.reshape(b, c, h, w)
    if REGISTRY[spec.method].solve_tensor is not None:  # solved where the tensor lies, anchored on the CPU
        results = solve_on_device(batch, spec)
    else:
        # One int64 copy, whose planes the tasks view (no float64 copy, no stacked copy).
        planes = batch.detach().to("cpu").to(torch.int64).reshape(b * c, h, w).numpy()
        results = run_planes(planes, spec, workers, group=c if REGISTRY[spec.method].joint_channels else 1)
        del planes
    # Filled plane by plane, in the output's dtype: no stacked int64 or float64 copy of the whole batch.
    restored = torch.empty(len(results), h, w, dtype=modulus.dtype)
    for plane, (r, _) in zip(restored, results, strict=True):
        plane.copy_(torch.from_numpy(r.astype(np.float64)))
    peak = max((float(r.max()) for r, _ in results if r.size), default=0.0)
    _warn_inexact(restored, peak)
    out = like_memory_format(restored.reshape(modulus.shape).to(device=modulus.device), modulus)
    infos = [i for _, i in results]

    def grid(key: str, dtype: torch.dtype) -> torch.Tensor:
        return torch.tensor([i[key] for i in infos], dtype=dtype).reshape(b, c)

    info = SingleShotInfo(
        energies=[[infos[bi * c + ci]["energies"] for ci in range(c)] for bi in range(b)],
        iterations=torch.tensor([len(i["steps"]) for i in infos], dtype=torch.int64).reshape(b, c),
        cuts=grid("cuts", torch.int64),
        energy=grid("energy", torch.float64),
        seconds=grid("seconds", torch.float64),
        method=spec.method,
    )
    if infos and all("confidence" in i for i in infos):
        maps = torch.from_numpy(np.stack([i["confidence"] for i in infos]))
        info.confidence = like_memory_format(
            maps.to(dtype=modulus.dtype).reshape(modulus.shape).to(device=modulus.device), modulus
        )
    return out, info


def _solve_mosaic(
    modulus: torch.Tensor, spec: SolverSpec, workers: int | None, cfa: str
) -> tuple[torch.Tensor, SingleShotInfo]:
    """Unwrap a mosaic of the colour filter array ``cfa``: its wrapped RGB interpolated on the circle, solved at full
    resolution as one colour image, then the photosites' own rollover counts (with ``"learned"``, refined in the
    cells' half-resolution colour images: :func:`_refine_photosites`); or, with ``"learned"``'s ``cells``, its
    photosites as two half-resolution colour images (:func:`_solve_cells`)."""
    check_cfa(cfa)
    check_floating(modulus, "modulus")
    check_image_shape(modulus, "modulus", 2, 4)
    check_nonempty_image(modulus, "modulus")
    if modulus.dim() > 2 and modulus.shape[-3] != 1:
        raise ValueError(
            f"modulus must be a mosaic with cfa={cfa!r}, (B, 1, H, W), (1, H, W) or (H, W); got {tuple(modulus.shape)}"
        )
    if solves_cells(spec):
        return _solve_cells(modulus, spec, workers, cfa)
    guide = interpolate_wrapped(modulus if modulus.dim() > 2 else modulus[None], cfa, spec.params.bits)
    out, info = _solve(guide, mosaic_spec(spec), workers)
    if info.confidence is not None:
        info.confidence = mosaic(info.confidence, cfa).reshape(modulus.shape)
    out = mosaic(out, cfa).reshape(modulus.shape)
    if refines_photosites(spec):
        out = _refine_photosites(modulus, out, spec, cfa, info)
    return out, info


def _refine_photosites(
    modulus: torch.Tensor, restored: torch.Tensor, spec: SolverSpec, cfa: str, info: SingleShotInfo
) -> torch.Tensor:
    """The guide's restored mosaic with its photosites' rollover counts moved by
    :func:`~torch_modulo.singleshot.learned.refine_photosites` in the two half-resolution colour images (R, G1, B)
    and (R, G2, B) of its cells (the first gives red, blue and the first green, the second the other green).

    Each refined plane keeps the guide's anchoring: it is moved by the one constant that leaves most of its counts
    where the guide put them (so the two greens, anchored together in the guide's green channel, stay together), and
    none is left below 0. An image with counts beyond its dtype's range (float16's inf) keeps the guide's. The
    bookkeeping is in int64 on the CPU; the networks run on the input's device. The refinement's time is added to
    ``info.seconds``."""
    start = time.perf_counter()
    h, w = modulus.shape[-2:]
    planes = split_planes(modulus.reshape(-1, 1, h, w))
    moduli = planes.to(device="cpu", dtype=torch.int64)
    period = spec.params.period
    k = (split_planes(restored.reshape(-1, 1, h, w)).to(device="cpu", dtype=torch.float64) - moduli) / period
    k = k.round()  # inf where the guide's counts passed the dtype's range
    r, g1, b, g2 = _cell_planes(cfa)
    for item in range(len(k)):
        if not bool(torch.isfinite(k[item]).all()):
            continue
        for image, keep in (([r, g1, b], (r, g1, b)), ([r, g2, b], (g2,))):
            guide = k[item, image].to(torch.int64).numpy()
            moved = refine_photosites(planes[item, image], guide, spec, tuple(image.index(p) for p in keep))
            for plane in keep:
                i = image.index(plane)
                k[item, plane] = torch.from_numpy(_keep_anchor(moved[i], guide[i])).to(k)
        info.seconds[item] += (time.perf_counter() - start) / info.seconds.shape[1]
        start = time.perf_counter()
    out = merge_planes(moduli + period * k).reshape(restored.shape)
    peak = float(out.nan_to_num(posinf=0.0).max()) if out.numel() else 0.0
    before = float(restored.nan_to_num(posinf=0.0).max()) if restored.numel() else 0.0
    out = like_memory_format(out.to(dtype=restored.dtype, device=restored.device), restored)
    if peak > before:  # a region moved up past what the guide restored: the dtype may not hold it
        _warn_inexact(out, peak)
    return out


def _cell_planes(cfa: str) -> tuple[int, int, int, int]:
    """The indices, among :func:`~torch_modulo.cfa.split_planes`' four planes of a ``cfa`` mosaic, of its red, first
    green, blue and second green photosites: (R, G1, B) and (R, G2, B) are the cells' two colour images."""
    colours = cfa_colours(cfa)
    g1, g2 = (i for i, c in enumerate(colours) if c == 1)
    return colours.index(0), g1, colours.index(2), g2


def _keep_anchor(moved: np.ndarray, guide: np.ndarray) -> np.ndarray:
    """``moved`` less the constant by which most of it differs from ``guide`` (so where nothing moved it is the
    guide's, anchored as the guide was), at least 0."""
    step = (moved - guide).ravel()
    low = int(step.min(initial=0))
    offset = int(np.bincount(step - low).argmax()) + low if step.size else 0
    return np.maximum(moved - offset, 0)


def _solve_cells(
    modulus: torch.Tensor, spec: SolverSpec, workers: int | None, cfa: str
) -> tuple[torch.Tensor, SingleShotInfo]:
    """A mosaic's photosites as two half-resolution colour images, (R, G1, B) and (R, G2, B) of every 2 x 2 cell
    (:func:`~torch_modulo.cfa.split_planes`), each solved as one colour image: no interpolated value is solved.

    The first image gives the red, blue and first green photosites, the second the other green ones; the info is the
    first image's (one entry per colour), its confidence that of each photosite's own plane.
    """
    h, w = modulus.shape[-2:]
    planes = split_planes(modulus.reshape(-1, 1, h, w))  # refuses odd sides, naming them
    r, g1, b, g2 = _cell_planes(cfa)
    first, info = _solve(planes[:, [r, g1, b]], spec, workers)
    second, info2 = _solve(planes[:, [r, g2, b]], spec, workers)
    order = [r, g1, b, g2]
    back = [order.index(i) for i in range(4)]  # the four solved planes back in the mosaic's order
    out = torch.cat([first, second[:, 1:2]], dim=1)[:, back]
    if info.confidence is not None and info2.confidence is not None:
        conf = torch.cat([info.confidence, info2.confidence[:, 1:2]], dim=1)[:, back]
        info.confidence = merge_planes(conf).reshape(modulus.shape)
    info.seconds = info.seconds + info2.seconds
    return like_memory_format(merge_planes(out).reshape(modulus.shape), modulus), info


@overload
def unwrap_single(
    modulus: torch.Tensor,
    bits: int = ...,
    *,
    method: str = ...,
    neighborhood: int = ...,
    a1: float = ...,
    a2: float = ...,
    x0: float | None = ...,
    sigma: int = ...,
    max_iter: int = ...,
    workers: int | None = ...,
    return_info: Literal[False] = ...,
    cfa: str | None = ...,
    **options: Any,
) -> torch.Tensor: ...


@overload
def unwrap_single(
    modulus: torch.Tensor,
    bits: int = ...,
    *,
    method: str = ...,
    neighborhood: int = ...,
    a1: float = ...,
    a2: float = ...,
    x0: float | None = ...,
    sigma: int = ...,
    max_iter: int = ...,
    workers: int | None = ...,
    return_info: Literal[True],
    cfa: str | None = ...,
    **options: Any,
) -> tuple[torch.Tensor, SingleShotInfo]: ...


@overload
def unwrap_single(
    modulus: torch.Tensor,
    bits: int = ...,
    *,
    method: str = ...,
    neighborhood: int = ...,
    a1: float = ...,
    a2: float = ...,
    x0: float | None = ...,
    sigma: int = ...,
    max_iter: int = ...,
    workers: int | None = ...,
    return_info: bool = ...,
    cfa: str | None = ...,
    **options: Any,
) -> torch.Tensor | tuple[torch.Tensor, SingleShotInfo]: ...


def unwrap_single(
    modulus: torch.Tensor,
    bits: int = 8,
    *,
    method: str = "learned",
    neighborhood: int = 8,
    a1: float = 0.1,
    a2: float = 1e-5,
    x0: float | None = None,
    sigma: int = 2,
    max_iter: int = 1000,
    workers: int | None = None,
    return_info: bool = False,
    cfa: str | None = None,
    **options: Any,
) -> torch.Tensor | tuple[torch.Tensor, SingleShotInfo]:
    """Recover the counts from one modulus image (paper Sec. 4, Eqs. 3-5).

    ``"paper"`` and ``"fast"`` minimise ``C(k) = sum V(I_i - I_j)`` over neighbour pairs of ``I = I_m + k 2**bits``
    with binary moves ``k <- k + delta`` (one s-t minimum cut each, PyMaxflow); ``"learned"`` (default) follows the
    pairs a trained network is surest of, ``"guided"`` the most reliable paths by second differences. Then ``k``
    is anchored: the darkest connected region holding at least 3% of the pixels (or 0.1% with mostly smooth
    borders) gets ``k = 0`` and nothing is left below it (``k >= 0``). Images are independent problems, and so are
    channels for the graph-cut methods; ``"guided"``, ``"fast"`` and ``"paper"`` solve them in parallel worker
    processes, ``"learned"`` and ``"lsq"`` the batch in this process, on its device. The energy settings
    (``neighborhood``, ``a1``, ``a2``, ``x0``) and ``sigma``, ``max_iter`` steer the graph-cut methods; for
    ``"learned"`` and ``"guided"`` they only define the energy reported.

    Args:
        modulus: integer-valued floating tensor in ``[0, 2**bits)``, shape (B, C, H, W), (C, H, W) or (H, W),
            on any device.
        bits: sensor bit depth ``N``.
        method: one of :data:`METHODS`: ``"learned"`` (default: a small network's jump probabilities per
            neighbour pair, the channels of an image together, decoded exactly:
            :mod:`torch_modulo.singleshot.learned`), ``"guided"`` (path following without a graph cut, the channels
            of an image together), ``"fast"`` (the paper's energy and moves on a cheaper schedule) or ``"paper"``
            (the published algorithm as printed, from ``k = 0``); ``"lsq"`` (least squares with the DCT and
            reweighting, in torch on ``modulus``'s device).
        neighborhood: 8 (the paper) or 4.
        a1: slope of the linear part of ``V`` (Eq. 5).
        a2: curvature of the quadratic part of ``V``.
        x0: breakpoint of ``V``; ``None`` means ``2**(bits - 1)``.
        sigma: the larger step tried when step-1 moves stop helping (paper: 2; 1 disables it).
        max_iter: the most global minimum cuts per plane.
        workers: worker processes; ``None`` uses ``min(planes, os.cpu_count())`` when the job is large enough to
            pay for a pool, else runs in-process; 1 always runs in-process, and so does any value inside a
            daemonic process (a DataLoader worker, say). Scripts that use a pool need the usual
            ``if __name__ == "__main__":`` guard. ``"learned"`` (the default) and ``"lsq"`` use none: they solve the
            batch in this process, on its device (``workers`` is ignored).
        return_info: also return a :class:`SingleShotInfo` (energy per iteration, iteration counts, timings; for
            ``"learned"`` the confidence map of the same run, :attr:`SingleShotInfo.confidence`).
        cfa: None, or the colour filter array of a mosaic (``"RGGB"``, ``"BGGR"``, ``"GRBG"``, ``"GBRG"``):
            ``modulus`` is then (B, 1, H, W), (1, H, W) or (H, W) with an even height and width. Its wrapped colours
            are interpolated on the circle to full resolution (:func:`torch_modulo.cfa.interpolate_wrapped`), that
            RGB image is unwrapped (the methods that solve channels together share one tree across the colours),
            and the restored mosaic keeps each photosite's own count; the info has one entry per colour (C = 3).
            ``"learned"`` then runs 4 min-cut moves after its tree and no level moves on the guide unless
            ``max_cuts`` or ``levels`` is given (:data:`~torch_modulo.singleshot.learned.MOSAIC_CUTS`), and moves
            the photosites' counts by its level moves in the two half-resolution colour images of the cells (the
            red, first green and blue photosites of every 2 x 2 cell, and the red, second green and blue ones:
            nothing interpolated) under those images' own network costs
            (:func:`~torch_modulo.singleshot.learned.refine_photosites`; not with ``levels=False``); with
            ``cells=True`` it instead solves those two images from their own trees.
            Demosaic the restored counts (:func:`torch_modulo.cfa.demosaic`), never the modulus.
        **options: method options. ``"fast"``: ``init`` (``"auto"``, ``"zeros"`` or ``"quality"``; default
            ``"auto"``), ``rel_tol`` (default 3e-4), ``window`` (default 64: the side of the windows of the
            local moves; 0 disables the local phase; formerly ``tile``),
            ``tile_pixels`` (default ``2**22``: larger images are solved in overlapping tiles of at most that many
            pixels, stitched on their overlaps, :mod:`torch_modulo.singleshot.tiles`; 0 never tiles).
            ``"guided"``: ``colour`` (default True: the channels of an image share one tree; False: each channel
            alone), ``denoise`` (default 0: the standard deviation in pixels of a Gaussian applied to the wrapped
            image's phasor first; about 0.7 for frames with noise in the low bits), ``tile_pixels`` (default
            ``2**22``: larger images build their spanning tree in blocks of at most that many pixels, which needs
            less memory and gives a minimum spanning tree of the same pairs; 0: the whole image at once).
            ``"learned"``: ``weights`` (default None: the weights shipped in the package; or a weights file),
            ``levels`` (default True: a small head's level costs move whole regions after the tree,
            :func:`~torch_modulo.singleshot.learned.region_moves`; a path: a level weights file; False: no level
            moves, faster; docs/singleshot.md has the numbers), ``max_cuts`` (default 0, 4 on a mosaic: the
            most likely tree alone; more: binary moves weighing every pair's probability after it, before the level
            moves),
            ``augment`` (default False: True averages the network over the image's four flips), ``tile`` (default
            768: the network and its level head predict tiles of that side with their context, which bounds
            memory; 0: the whole image), ``threads`` (default 0: all of torch's threads for the networks on the
            CPU; 1 is faster on cores shared with other jobs), ``cells`` (default False; see ``cfa``). ``"lsq"``:
            ``iterations`` (default 3: reweighting rounds; 0: the unweighted solution, one DCT solve),
            ``cg_iterations`` (default 10: conjugate-gradient steps per round), ``colour`` (default True: the
            channels of an image share their weights; False: each channel alone).

    Returns:
        The restored counts ``I_m + k 2**bits``: same shape, dtype, device and memory format (channels_last
        included) as ``modulus``; with ``return_info=True`` a tuple ``(restored, info)``. Counts beyond the integers
        the dtype holds exactly are rounded, with a warning that says which dtype would hold them (float16 counts
        above 65504 become inf, and the warning counts them).

    Raises:
        TypeError: ``modulus`` is not a floating tensor, or an argument has the wrong type.
        ValueError: values outside ``[0, 2**bits)``, NaN or non-integer values, an empty image, a wrong number
            of dimensions, a modulus on the ``meta`` device (no values to solve, with the checks off too), or an
            invalid setting.

    Example:
        >>> ramp = torch.arange(0.0, 1200.0, 40.0).reshape(1, -1).repeat(4, 1)  # counts 0 .. 1160
        >>> restored = unwrap_single(ramp % 256, bits=8)
        >>> bool(torch.equal(restored, ramp))
        True
    """
    spec = make_spec(bits, method, neighborhood, a1, a2, x0, sigma, max_iter, options)
    check_flag(return_info, "return_info")
    workers = check_workers(workers)
    out, info = _solve(modulus, spec, workers) if cfa is None else _solve_mosaic(modulus, spec, workers, cfa)
    return (out, info) if return_info else out


class SingleShotUnwrap(nn.Module):
    """Module twin of :func:`unwrap_single` (paper Sec. 4). Not differentiable (the output is a choice of ``k``).

    Args:
        bits: sensor bit depth ``N``.
        method: one of :data:`METHODS` (see :func:`unwrap_single`); ``"learned"`` by default.
        neighborhood: 8 (the paper) or 4.
        a1: slope of the linear part of ``V``.
        a2: curvature of the quadratic part of ``V``.
        x0: breakpoint of ``V``; ``None`` means ``2**(bits - 1)``.
        sigma: the larger step (paper: 2).
        max_iter: the most global minimum cuts per plane.
        workers: worker processes (see :func:`unwrap_single`).
        cfa: None, or the colour filter array of mosaicked input (see :func:`unwrap_single`).
        **options: method options (see :func:`unwrap_single`).

    Shape:
        - Input: (B, C, H, W), (C, H, W) or (H, W).
        - Output: same as the input, in its memory format (channels_last included).

    Example:
        >>> unwrap = SingleShotUnwrap(bits=8)
        >>> unwrap(torch.tensor([[200.0, 250.0, 44.0, 94.0]]))  # counts 200, 250, 300, 350
        tensor([[200., 250., 300., 350.]])
    """

    def __init__(
        self,
        bits: int = 8,
        *,
        method: str = "learned",
        neighborhood: int = 8,
        a1: float = 0.1,
        a2: float = 1e-5,
        x0: float | None = None,
        sigma: int = 2,
        max_iter: int = 1000,
        workers: int | None = None,
        cfa: str | None = None,
        **options: Any,
    ) -> None:
        super().__init__()
        self.spec = make_spec(bits, method, neighborhood, a1, a2, x0, sigma, max_iter, options)
        self.workers = check_workers(workers)
        self.bits = self.spec.params.bits
        self.method = method
        self.cfa = check_cfa(cfa) if cfa is not None else None

    def forward(self, modulus: torch.Tensor) -> torch.Tensor:
        p = self.spec.params
        out = unwrap_single(
            modulus,
            p.bits,
            method=self.spec.method,
            neighborhood=self.spec.neighborhood,
            a1=p.a1,
            a2=p.a2,
            x0=p.x0,
            sigma=self.spec.sigma,
            max_iter=self.spec.max_iter,
            workers=self.workers,
            cfa=self.cfa,
            **dict(self.spec.options),
        )
        return out
