"""The single-shot unwrapping energy of the paper (Sec. 4.1-4.2): Eqs. 3, 4 and 5.

The restored image is :math:`\\hat I = I_m + k\\,2^N` (Eq. 2). Its energy (Eq. 3) sums a clique potential over
every unordered pair of neighbouring pixels (the 8-neighbourhood of the paper, or the 4-neighbourhood):

.. math:: C(k \\mid I_m) = \\sum_{(i, j) \\in \\mathbb{G}} V(\\hat I_i - \\hat I_j)

with the piecewise potential of Eq. 5,

.. math:: V(x) = a_1 |x| \\ (|x| \\le x_0), \\qquad V(x) = a_2 x^2 + b \\ (|x| > x_0),

where :math:`a_1 = 0.1`, :math:`a_2 = 10^{-5}`, :math:`x_0 = 2^{N-1}` and :math:`b = a_1 x_0 - a_2 x_0^2` makes
``V`` continuous. A pair term of a binary move with step ``s`` is graph-representable (Eq. 4) where
:math:`V(x + s 2^N) + V(x - s 2^N) \\ge 2 V(x)`.

The torch functions here work on any device and dtype and are differentiable almost everywhere; the solvers
in :mod:`torch_modulo.singleshot.graphcut` use the numpy twins (:func:`potential_np`, :func:`energy_np`), which
share :class:`EnergyParams` so both sides compute the same numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from torch_modulo._checks import check_bits, check_finite, check_floating, check_image_shape, check_int, check_real
from torch_modulo.singleshot.grid import pair_offsets, pair_slices

__all__ = [
    "EnergyParams",
    "Potential",
    "UnwrapEnergy",
    "energy_np",
    "is_representable",
    "pair_offsets",  # re-exported from grid, where it lives
    "potential",
    "potential_np",
    "unwrap_energy",
]


@dataclass(frozen=True)
class EnergyParams:
    """Parameters of the potential ``V`` of Eq. 5 for a ``bits``-bit modulus.

    Build with :meth:`make`, which validates the values and fills in the defaults of the paper.

    Attributes:
        bits: the sensor bit depth ``N``; the period is ``2**bits``.
        a1: slope of the linear part.
        a2: curvature of the quadratic part.
        x0: where the two parts meet (``2**(bits - 1)`` by default).
        b: offset of the quadratic part, ``a1 * x0 - a2 * x0**2``, which makes ``V`` continuous.
    """

    bits: int
    a1: float
    a2: float
    x0: float
    b: float

    @property
    def period(self) -> int:
        """The modulus period ``2**bits``."""
        return 1 << self.bits

    @classmethod
    def make(cls, bits: int = 8, a1: float = 0.1, a2: float = 1e-5, x0: float | None = None) -> EnergyParams:
        """Validate the parameters of Eq. 5 and compute ``b``.

        Raises:
            TypeError: ``bits`` is not an integer or a parameter is not a real number.
            ValueError: ``bits < 1``, ``a1`` or ``a2`` negative, ``x0`` not positive, or a value not finite.
        """
        bits = check_bits(bits, torch.float64)
        a1 = check_real(a1, "a1", 0)
        a2 = check_real(a2, "a2", 0)
        x0 = check_real(float(2 ** (bits - 1)) if x0 is None else x0, "x0", positive=True)
        return cls(bits=bits, a1=a1, a2=a2, x0=x0, b=a1 * x0 - a2 * x0**2)


def potential_np(x: np.ndarray, p: EnergyParams) -> np.ndarray:
    """Eq. 5 on a numpy array (float64 result): the numpy twin of :func:`potential`.

    Example:
        >>> potential_np(np.array([0.0, -100.0]), EnergyParams.make(8)).tolist()
        [0.0, 10.0]
    """
    ax = np.abs(np.asarray(x, dtype=np.float64))
    return np.where(ax <= p.x0, p.a1 * ax, p.a2 * ax * ax + p.b)


def energy_np(restored: np.ndarray, p: EnergyParams, offsets: tuple[tuple[int, int], ...]) -> float:
    """Eq. 3 of one (H, W) plane in numpy (float64): the numpy twin of :func:`unwrap_energy`.

    Example:
        >>> energy_np(np.array([[0, 10], [20, 30]]), EnergyParams.make(8), pair_offsets(4))
        6.0
    """
    h, w = restored.shape
    total = 0.0
    for off in offsets:
        first, second = pair_slices(h, w, off)
        d = restored[first].astype(np.float64) - restored[second]
        total += float(potential_np(d, p).sum())
    return total


def potential(
    x: torch.Tensor, bits: int = 8, *, a1: float = 0.1, a2: float = 1e-5, x0: float | None = None
) -> torch.Tensor:
    """The clique potential ``V`` of Eq. 5, elementwise.

    ``V(x) = a1 |x|`` for ``|x| <= x0`` and ``a2 x**2 + b`` beyond, with ``b = a1 x0 - a2 x0**2`` (continuous).
    ``V`` is even, so it may be given signed differences.

    Args:
        x: floating tensor of pixel differences, any shape.
        bits: sensor bit depth ``N``; sets the default ``x0 = 2**(N - 1)``.
        a1: slope of the linear part (paper: 0.1).
        a2: curvature of the quadratic part (paper: 1e-5).
        x0: breakpoint; ``None`` means ``2**(bits - 1)``.

    Returns:
        ``V(x)``, same shape, dtype and device as ``x``.

    Example:
        >>> potential(torch.tensor([0.0, -100.0, 128.0, 256.0]), bits=8)
        tensor([ 0.0000, 10.0000, 12.8000, 13.2915])
    """
    check_floating(x, "x")
    check_finite(x, "x")
    p = EnergyParams.make(bits, a1, a2, x0)
    ax = x.abs()
    return torch.where(ax <= p.x0, p.a1 * ax, p.a2 * ax * ax + p.b)


def is_representable(
    x: torch.Tensor,
    bits: int = 8,
    *,
    a1: float = 0.1,
    a2: float = 1e-5,
    x0: float | None = None,
    step: int = 1,
) -> torch.Tensor:
    """Eq. 4: whether a pair term with difference ``x`` is graph-representable in a move of ``step`` periods.

    A binary move ``k <- k + step * delta`` turns the pair term ``V(x)`` into a function of two binary
    variables; it can be cut exactly iff ``V(x + step 2^N) + V(x - step 2^N) >= 2 V(x)`` (Kolmogorov and Zabih).
    Where it is not, the solver drops the pairwise edge (PUMA, Bioucas-Dias and Valadao 2007). Equality holds up to
    a few units of rounding.

    Args:
        x: floating tensor of differences ``I_i - I_j`` of the restored image.
        bits: sensor bit depth ``N``.
        a1: slope of the linear part of ``V``.
        a2: curvature of the quadratic part of ``V``.
        x0: breakpoint of ``V``; ``None`` means ``2**(bits - 1)``.
        step: the move's step in periods (1, or the paper's ``sigma = 2``).

    Returns:
        Boolean tensor, same shape and device as ``x``.

    Example:
        >>> is_representable(torch.tensor([0.0, 100.0, 200.0]), bits=8)
        tensor([ True,  True, False])
    """
    check_floating(x, "x")
    check_finite(x, "x")
    step = check_int(step, "step", 1)
    p = EnergyParams.make(bits, a1, a2, x0)
    shift = float(step * p.period)
    v2 = 2 * potential(x, bits, a1=a1, a2=a2, x0=x0)
    lhs = potential(x + shift, bits, a1=a1, a2=a2, x0=x0) + potential(x - shift, bits, a1=a1, a2=a2, x0=x0)
    # Equality (e.g. on a linear stretch of V) must not fail on rounding: allow a few ulps.
    slack = 8 * torch.finfo(x.dtype).eps * (lhs.abs() + v2.abs())
    return lhs >= v2 - slack


def unwrap_energy(
    restored: torch.Tensor,
    bits: int = 8,
    *,
    neighborhood: int = 8,
    a1: float = 0.1,
    a2: float = 1e-5,
    x0: float | None = None,
) -> torch.Tensor:
    """Eq. 3: the energy ``C(k | I_m) = sum V(I_i - I_j)`` of a restored image, per image and channel.

    Each unordered neighbour pair counts once; pairs are not wrapped around the border.

    Args:
        restored: restored counts ``I_m + k 2**bits`` (or any image), shape (B, C, H, W), (C, H, W) or (H, W).
        bits: sensor bit depth ``N``.
        neighborhood: 8 (the paper) or 4.
        a1: slope of the linear part of ``V``.
        a2: curvature of the quadratic part of ``V``.
        x0: breakpoint of ``V``; ``None`` means ``2**(bits - 1)``.

    Returns:
        The energy with the spatial dimensions summed out: (B, C), (C,) or a scalar; ``restored``'s dtype
        (float32 for float16 and bfloat16, which are summed in float32: a float16 energy of a 64 x 64 image
        already passes 65504) and device. Differentiable almost everywhere.

    Example:
        >>> img = torch.tensor([[0.0, 10.0], [20.0, 30.0]])
        >>> unwrap_energy(img, neighborhood=4)  # 0.1 * (10 + 10 + 20 + 20)
        tensor(6.)
    """
    check_floating(restored, "restored")
    check_image_shape(restored, "restored", 2, 4)
    check_finite(restored, "restored")
    offsets = pair_offsets(neighborhood)
    p = EnergyParams.make(bits, a1, a2, x0)
    if restored.dtype in (torch.float16, torch.bfloat16):
        restored = restored.float()
    h, w = restored.shape[-2:]
    total = restored.new_zeros(restored.shape[:-2])
    for off in offsets:
        first, second = pair_slices(h, w, off)
        d = restored[(..., *first)] - restored[(..., *second)]
        total = total + potential(d, p.bits, a1=p.a1, a2=p.a2, x0=p.x0).sum(dim=(-2, -1))
    return total


class Potential(nn.Module):
    """Module twin of :func:`potential` (Eq. 5).

    Args:
        bits: sensor bit depth ``N``.
        a1: slope of the linear part.
        a2: curvature of the quadratic part.
        x0: breakpoint; ``None`` means ``2**(bits - 1)``.

    Shape:
        - Input: any shape.
        - Output: same as the input.

    Example:
        >>> Potential(bits=8)(torch.tensor([64.0]))
        tensor([6.4000])
    """

    def __init__(self, bits: int = 8, *, a1: float = 0.1, a2: float = 1e-5, x0: float | None = None) -> None:
        super().__init__()
        p = EnergyParams.make(bits, a1, a2, x0)
        self.bits, self.a1, self.a2, self.x0 = p.bits, p.a1, p.a2, p.x0

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return potential(x, self.bits, a1=self.a1, a2=self.a2, x0=self.x0)


class UnwrapEnergy(nn.Module):
    """Module twin of :func:`unwrap_energy` (Eq. 3).

    Args:
        bits: sensor bit depth ``N``.
        neighborhood: 8 (the paper) or 4.
        a1: slope of the linear part of ``V``.
        a2: curvature of the quadratic part of ``V``.
        x0: breakpoint of ``V``; ``None`` means ``2**(bits - 1)``.

    Shape:
        - Input: (B, C, H, W), (C, H, W) or (H, W).
        - Output: (B, C), (C,) or a scalar.

    Example:
        >>> UnwrapEnergy(bits=8, neighborhood=4)(torch.zeros(1, 3, 4, 4))
        tensor([[0., 0., 0.]])
    """

    def __init__(
        self,
        bits: int = 8,
        *,
        neighborhood: int = 8,
        a1: float = 0.1,
        a2: float = 1e-5,
        x0: float | None = None,
    ) -> None:
        super().__init__()
        p = EnergyParams.make(bits, a1, a2, x0)
        pair_offsets(neighborhood)
        self.neighborhood = int(neighborhood)
        self.bits, self.a1, self.a2, self.x0 = p.bits, p.a1, p.a2, p.x0

    def forward(self, restored: torch.Tensor) -> torch.Tensor:
        return unwrap_energy(restored, self.bits, neighborhood=self.neighborhood, a1=self.a1, a2=self.a2, x0=self.x0)
