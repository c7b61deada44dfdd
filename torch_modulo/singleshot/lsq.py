"""Least-squares unwrapping with the DCT (Ghiglia and Romero, JOSA A 1994): ``method="lsq"``, on the input's device.

The rollover counts are read off the image ``phi`` whose differences are closest, in the least-squares sense, to
the wrapped differences of the modulus ``I_m`` (each wrapped into ``[-2^(N-1), 2^(N-1))``). The normal equations
are a Poisson equation with Neumann boundaries, ``laplacian(phi) = div(wrapped differences)``, which the 2-D DCT-II
diagonalises, so one forward and one inverse DCT solve it (:func:`poisson_neumann`). A few rounds of iteratively
reweighted least squares then let the solution step across the pairs that disagree with it (:func:`lsq_phase`),
and ``phi`` is snapped to the measurement: ``k = round((phi - I_m) / 2^N)`` (:func:`snap_k`), so every output is
exactly ``I_m + k 2^N``.

Everything is torch, batched over every leading dimension, on the input's device, in float64 (float32 on devices
without float64, :func:`work_dtype`). The DCT is computed with one real FFT of the signal's own length (:func:`dct`,
:func:`idct`).

Example:
    >>> ramp = torch.arange(0.0, 1200.0, 40.0).repeat(4, 1)  # counts 0 .. 1160
    >>> k = lsq_k(ramp % 256, bits=8, iterations=3)
    >>> bool(torch.equal(ramp % 256 + 256 * k, ramp))
    True
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from torch_modulo._checks import check_flag, check_int
from torch_modulo.singleshot.spec import MoveStats, SolverSpec

__all__ = [
    "LSQ_OPTIONS",
    "dct",
    "idct",
    "lsq_k",
    "lsq_phase",
    "poisson_neumann",
    "snap_k",
    "solve_lsq",
    "solve_lsq_tensor",
    "work_dtype",
    "wrapped_gradients",
]


def work_dtype(device: torch.device) -> torch.dtype:
    """The floating dtype the solver works in on ``device``: float64, or float32 where float64 is missing (MPS).

    Example:
        >>> work_dtype(torch.device("cpu"))
        torch.float64
    """
    return torch.float32 if device.type == "mps" else torch.float64


def _twiddle(n: int, like: torch.Tensor) -> torch.Tensor:
    """``exp(-i pi k / (2 n))`` for ``k = 0 .. n // 2``, complex, on ``like``'s device and precision."""
    angle = torch.arange(n // 2 + 1, device=like.device, dtype=like.dtype) * (-math.pi / (2 * n))
    return torch.polar(torch.ones_like(angle), angle)


def dct(x: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Unnormalised DCT-II along ``dim``: ``X[k] = sum_n x[n] cos(pi k (2 n + 1) / (2 N))``.

    Computed with one real FFT of length ``N`` (Makhoul's reordering: even samples forward, odd samples reversed).

    Args:
        x: real floating tensor.
        dim: the dimension to transform.

    Returns:
        The coefficients, shape and dtype of ``x``.

    Example:
        >>> x = torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
        >>> n = torch.arange(3, dtype=torch.float64)
        >>> direct = torch.stack([(x * torch.cos(torch.pi * k * (2 * n + 1) / 6)).sum() for k in range(3)])
        >>> bool(torch.allclose(dct(x), direct))
        True
    """
    x = x.movedim(dim, -1)
    n = x.shape[-1]
    v = torch.cat([x[..., ::2], x[..., 1::2].flip(-1)], dim=-1)
    z = torch.fft.rfft(v, dim=-1) * _twiddle(n, x)
    out = torch.cat([z.real, -z.imag[..., 1 : n - n // 2].flip(-1)], dim=-1)
    return out.movedim(-1, dim)


def idct(coeffs: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """The exact inverse of :func:`dct` along ``dim`` (a scaled DCT-III).

    Example:
        >>> x = torch.tensor([[1.0, -2.0, 5.0, 0.5]], dtype=torch.float64)
        >>> bool(torch.allclose(idct(dct(x)), x))
        True
    """
    c = coeffs.movedim(dim, -1)
    n = c.shape[-1]
    half = n // 2 + 1
    mirrored = torch.cat([torch.zeros_like(c[..., :1]), c[..., 1:].flip(-1)], dim=-1)[..., :half]  # X[n - k]
    spectrum = torch.complex(c[..., :half], -mirrored) * _twiddle(n, c).conj()
    v = torch.fft.irfft(spectrum, n=n, dim=-1)
    x = torch.empty_like(v)
    x[..., ::2] = v[..., : (n + 1) // 2]
    x[..., 1::2] = v[..., (n + 1) // 2 :].flip(-1)
    return x.movedim(-1, dim)


def _laplacian_eigenvalues(h: int, w: int, like: torch.Tensor) -> torch.Tensor:
    """Eigenvalues ``2 cos(pi i / H) + 2 cos(pi j / W) - 4`` of the Neumann Laplacian in the DCT-II basis, (H, W)."""
    ey = 2 * torch.cos(torch.arange(h, device=like.device, dtype=like.dtype) * (math.pi / h)) - 2
    ex = 2 * torch.cos(torch.arange(w, device=like.device, dtype=like.dtype) * (math.pi / w)) - 2
    return ey[:, None] + ex[None, :]


def poisson_neumann(rho: torch.Tensor) -> torch.Tensor:
    """Solve ``laplacian(phi) = rho`` on every (H, W) plane with Neumann (mirror) boundaries, mean of ``phi`` zero.

    The 5-point Laplacian with mirrored borders is diagonal in the 2-D DCT-II basis; the constant mode (the one
    the equation leaves free) is set to 0.

    Args:
        rho: real floating tensor (..., H, W); it should sum to 0 over each plane (a divergence does).

    Returns:
        ``phi``, shape and dtype of ``rho``.

    Example:
        >>> phi = torch.tensor([[0.0, 1.0, 4.0], [1.0, 2.0, 5.0]], dtype=torch.float64)
        >>> lap = -phi * torch.tensor([[2.0, 3.0, 2.0], [2.0, 3.0, 2.0]], dtype=torch.float64)
        >>> lap[:, 1:] += phi[:, :-1]; lap[:, :-1] += phi[:, 1:]; lap[1:] += phi[:-1]; lap[:-1] += phi[1:]
        >>> bool(torch.allclose(poisson_neumann(lap), phi - phi.mean()))
        True
    """
    h, w = rho.shape[-2:]
    coeffs = dct(dct(rho, -1), -2)
    eig = _laplacian_eigenvalues(h, w, rho)
    eig[0, 0] = 1.0
    coeffs = coeffs / eig
    coeffs[..., 0, 0] = 0.0
    return idct(idct(coeffs, -2), -1)


def wrapped_gradients(modulus: torch.Tensor, period: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The wrapped forward differences of every plane, each in ``[-period / 2, period / 2)``, zero-padded.

    Returns:
        ``(gx, gy)``, both of ``modulus``'s shape: ``gx[..., i, j]`` is the wrapped step from ``(i, j)`` to
        ``(i, j + 1)`` (0 in the last column), ``gy`` the step to ``(i + 1, j)`` (0 in the last row).

    Example:
        >>> gx, gy = wrapped_gradients(torch.tensor([[250.0, 4.0, 10.0]]), 256)
        >>> gx.tolist(), gy.tolist()
        ([[10.0, 6.0, 0.0]], [[0.0, 0.0, 0.0]])
    """
    half = period / 2
    gx = torch.zeros_like(modulus)
    gy = torch.zeros_like(modulus)
    gx[..., :, :-1] = torch.remainder(modulus[..., :, 1:] - modulus[..., :, :-1] + half, period) - half
    gy[..., :-1, :] = torch.remainder(modulus[..., 1:, :] - modulus[..., :-1, :] + half, period) - half
    return gx, gy


def _divergence(gx: torch.Tensor, gy: torch.Tensor) -> torch.Tensor:
    """The backward-difference divergence of zero-padded forward differences (the adjoint of minus the gradient)."""
    div = gx.clone()
    div[..., :, 1:] -= gx[..., :, :-1]
    div += gy
    div[..., 1:, :] -= gy[..., :-1, :]
    return div


def _gradients(phi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Forward differences of every plane, zero in the last column (x) and the last row (y)."""
    gx = torch.zeros_like(phi)
    gy = torch.zeros_like(phi)
    gx[..., :, :-1] = phi[..., :, 1:] - phi[..., :, :-1]
    gy[..., :-1, :] = phi[..., 1:, :] - phi[..., :-1, :]
    return gx, gy


def _plane_dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return (a * b).sum(dim=(-2, -1), keepdim=True)


def _safe_ratio(num: torch.Tensor, den: torch.Tensor) -> torch.Tensor:
    """``num / den`` where ``den > 0``, else 0 (a plane whose search direction vanished stops moving)."""
    ok = den > 0
    return torch.where(ok, num / torch.where(ok, den, torch.ones_like(den)), torch.zeros_like(num))


def _weighted_solve(
    phi: torch.Tensor, gx: torch.Tensor, gy: torch.Tensor, wx: torch.Tensor, wy: torch.Tensor, steps: int
) -> torch.Tensor:
    """``steps`` of conjugate gradients on ``min sum w (grad(phi) - g)^2``, preconditioned by the DCT solver.

    The normal equations are ``-div(w grad(phi)) = -div(w g)``; the preconditioner solves the unweighted ones
    (Ghiglia and Romero's PCG). The step count is fixed (no data-dependent stop: no device synchronisation).
    """
    rhs = -_divergence(wx * gx, wy * gy)

    def apply(x: torch.Tensor) -> torch.Tensor:
        dx, dy = _gradients(x)
        return -_divergence(wx * dx, wy * dy)

    r = rhs - apply(phi)
    z = -poisson_neumann(r)
    direction = z
    rz = _plane_dot(r, z)
    for _ in range(steps):
        a_dir = apply(direction)
        alpha = _safe_ratio(rz, _plane_dot(direction, a_dir))
        phi = phi + alpha * direction
        r = r - alpha * a_dir
        z = -poisson_neumann(r)
        rz_next = _plane_dot(r, z)
        direction = z + _safe_ratio(rz_next, rz) * direction
        rz = rz_next
    return phi


def lsq_phase(
    modulus: torch.Tensor, bits: int, *, iterations: int = 0, cg_iterations: int = 10, colour: bool = False
) -> torch.Tensor:
    """The least-squares integral of the wrapped differences of every (H, W) plane (up to a constant per plane).

    With ``iterations = 0`` this is Ghiglia and Romero's unweighted solution: one Poisson solve with the DCT.
    Each further iteration reweights the pairs by ``eps / (e^2 + eps)``, where ``e`` is the gap between the
    current solution's difference and the wrapped one and ``eps = (2**bits / 80)^2``, and takes ``cg_iterations``
    steps of DCT-preconditioned conjugate gradients on the weighted problem: iteratively reweighted least squares
    towards the minimum-L0 solution (the minimum Lp-norm unwrapping of Ghiglia and Romero, JOSA A 1996, with
    ``p = 0``). A pair that the image really steps across by more than half a period then stops pulling the
    solution around it.

    Args:
        modulus: real tensor (..., H, W) of counts in ``[0, 2**bits)``, on any device.
        bits: sensor bit depth ``N``.
        iterations: reweighting rounds (0: the unweighted solution).
        cg_iterations: conjugate-gradient steps per round.
        colour: the planes along dimension -3 (the channels of an image) share their weights, from the root sum
            of squares of their gaps (needs at least 3 dimensions; else ignored).

    Returns:
        ``phi`` (..., H, W) in :func:`work_dtype` of the device, mean zero per plane.

    Example:
        >>> phi = lsq_phase(torch.tensor([[200.0, 250.0, 44.0, 94.0]]), 8)  # counts 200, 250, 300, 350
        >>> [round(v) for v in phi[0].tolist()]
        [-75, -25, 25, 75]
    """
    m = modulus.to(work_dtype(modulus.device))
    period = float(2**bits)
    gx, gy = wrapped_gradients(m, period)
    phi = poisson_neumann(_divergence(gx, gy))
    eps = (period / 80) ** 2
    share = colour and m.dim() >= 3
    for _ in range(iterations):
        dx, dy = _gradients(phi)
        ex, ey = (dx - gx).square(), (dy - gy).square()
        if share:
            ex, ey = ex.sum(dim=-3, keepdim=True), ey.sum(dim=-3, keepdim=True)
        phi = _weighted_solve(phi, gx, gy, eps / (ex + eps), eps / (ey + eps), cg_iterations)
    return phi


def snap_k(modulus: torch.Tensor, phi: torch.Tensor, bits: int) -> torch.Tensor:
    """Rollover counts that bring ``I_m + k 2**bits`` nearest to ``phi + c``, with ``c`` one constant per plane.

    ``c`` is the circular mean of the residual ``phi - I_m`` modulo ``2**bits``: the shift that brings ``phi``
    closest to the measurement, so that snapping does not split a flat region whose residual sits near half a
    period. The result is moved so that its smallest ``k`` is 0.

    Args:
        modulus: real tensor (..., H, W) of integer counts in ``[0, 2**bits)``.
        phi: an estimate of the counts up to a constant per plane, same shape, on the same device.
        bits: sensor bit depth ``N``.

    Returns:
        int64 ``k`` of ``modulus``'s shape, on its device; ``min k = 0`` per plane.

    Example:
        >>> snap_k(torch.tensor([[200.0, 10.0]]), torch.tensor([[-1000.0, -934.0]]), 8).tolist()
        [[0, 1]]
    """
    if modulus.numel() == 0:
        return torch.zeros(modulus.shape, dtype=torch.int64, device=modulus.device)
    residual = (phi - modulus.to(phi.dtype)) / float(2**bits)
    turns = torch.polar(torch.ones_like(residual), (2 * math.pi) * residual).mean(dim=(-2, -1), keepdim=True)
    k = torch.round(residual - torch.angle(turns) / (2 * math.pi))
    return (k - k.amin(dim=(-2, -1), keepdim=True)).to(torch.int64)


def lsq_k(
    modulus: torch.Tensor, bits: int, *, iterations: int = 0, cg_iterations: int = 10, colour: bool = False
) -> torch.Tensor:
    """Rollover counts of every (H, W) plane, up to one constant per plane: :func:`lsq_phase` snapped by
    :func:`snap_k` (arguments as there).

    Returns:
        int64 ``k`` of ``modulus``'s shape, on its device, ``min k = 0`` per plane: ``I_m + k 2**bits`` is the
        restored image, exactly consistent with the measurement.

    Example:
        >>> lsq_k(torch.tensor([[200.0, 250.0, 44.0, 94.0]]), 8).tolist()
        [[0, 0, 1, 1]]
    """
    if modulus.numel() == 0:
        return torch.zeros(modulus.shape, dtype=torch.int64, device=modulus.device)
    phi = lsq_phase(modulus, bits, iterations=iterations, cg_iterations=cg_iterations, colour=colour)
    return snap_k(modulus, phi, bits)


# ------------------------------------------------------------------------------------------------------- registry


def _check_rounds(value: object, name: str) -> int:
    return check_int(value, name, 0)


def _check_steps(value: object, name: str) -> int:
    return check_int(value, name, 1)


#: The options of ``method="lsq"``: name -> (default, check). ``iterations``: reweighting rounds (0: the
#: unweighted solution); ``cg_iterations``: conjugate-gradient steps per round; ``colour``: the channels of an
#: image share their weights.
LSQ_OPTIONS: dict[str, tuple[Any, Callable[[Any, str], Any]]] = {
    "iterations": (3, _check_rounds),
    "cg_iterations": (10, _check_steps),
    "colour": (True, check_flag),
}


def solve_lsq_tensor(moduli: torch.Tensor, spec: SolverSpec) -> tuple[torch.Tensor, None]:
    """The registry's tensor solver: (B, C, H, W) moduli on any device to int64 ``k`` there (not anchored), and no
    confidence.

    Options (``spec.option``): :data:`LSQ_OPTIONS`.
    """
    k = lsq_k(
        moduli.detach(),
        spec.params.bits,
        iterations=int(spec.option("iterations")),
        cg_iterations=int(spec.option("cg_iterations")),
        colour=bool(spec.option("colour")),
    )
    return k, None


def solve_lsq(moduli: np.ndarray, spec: SolverSpec, stats: list[MoveStats]) -> np.ndarray:
    """The registry's group solver (numpy in and out, on the CPU): (G, H, W) int64 moduli, taken as the channels of
    one image, to restored counts (not anchored). :func:`~torch_modulo.singleshot.unwrap_single` uses
    :func:`solve_lsq_tensor` instead, on the input's device."""
    start = time.perf_counter()
    k = solve_lsq_tensor(torch.from_numpy(np.asarray(moduli, dtype=np.float64))[None], spec)[0][0]
    restored = moduli + spec.params.period * k.numpy()
    for st in stats:
        st.tick("lsq", start)
    return restored
