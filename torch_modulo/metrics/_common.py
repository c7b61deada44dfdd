"""What the metrics share: input validation, the PSNR formula and the log coordinates relative to a reference."""

from __future__ import annotations

import math

import torch

from torch_modulo._checks import check_nonnegative, check_real, check_tensor


def real_image(x: object, name: str) -> torch.Tensor:
    """A real (floating or integer, not bool or complex) tensor with 2 to 4 dimensions."""
    x = check_tensor(x, name)
    if x.dtype == torch.bool or x.is_complex():
        raise TypeError(f"{name} must hold real numbers; got dtype {x.dtype}")
    if not 2 <= x.dim() <= 4:
        raise ValueError(f"{name} must have shape (B, C, H, W), (C, H, W) or (H, W); got {tuple(x.shape)}")
    return x


def image_pair(x: object, y: object, names: tuple[str, str]) -> tuple[torch.Tensor, torch.Tensor]:
    """Validate two images of the same shape and return them as ``(B, C, H, W)`` views."""
    x = real_image(x, names[0])
    y = real_image(y, names[1])
    if x.shape != y.shape:
        raise ValueError(
            f"{names[0]} and {names[1]} must have the same shape; got {tuple(x.shape)} and {tuple(y.shape)}"
        )
    if x.device != y.device:
        raise ValueError(f"{names[0]} and {names[1]} must be on the same device; got {x.device} and {y.device}")
    return as_bchw(x), as_bchw(y)


def as_bchw(x: torch.Tensor) -> torch.Tensor:
    if x.dim() == 2:
        return x[None, None]
    if x.dim() == 3:
        return x[None]
    return x


def float_pair(x: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Promote to a common floating dtype (integer inputs become the default float dtype)."""
    dtype = torch.promote_types(x.dtype, y.dtype)
    if not dtype.is_floating_point:
        dtype = torch.get_default_dtype()
    return x.to(dtype), y.to(dtype)


#: How ``peak`` and the other positive options are described when they are not.
POSITIVE = "positive and finite"


def psnr_bchw(x: torch.Tensor, y: torch.Tensor, peak: float) -> torch.Tensor:
    """``10 log10(peak^2 / MSE)`` per batch item of two ``(B, C, H, W)`` float tensors; +inf where they match.

    Computed in float64 (float32 on MPS, which has no float64) as ``20 log10(peak) - 10 log10(MSE)``, and with the
    differences scaled by their largest magnitude where squaring them would leave that dtype's range, so huge or
    tiny values that differ give a finite score; returned in ``x``'s dtype.
    """
    work = torch.float32 if x.device.type == "mps" else torch.float64
    d = (x.to(work) - y.to(work)).flatten(1)
    mag = d.detach().abs().amax(dim=1) if d.shape[1] else d.new_zeros(d.shape[0])
    edge = math.sqrt(torch.finfo(work).max) * 2.0**-32  # squares and their sums stay far inside the range
    rescale = (mag > edge) | ((mag > 0) & (mag < 1.0 / edge))
    s = torch.where(rescale, mag, torch.ones_like(mag))
    mse = (d / s[:, None]).square().mean(dim=1)
    score = 20.0 * math.log10(peak) - 10.0 * torch.log10(mse) - 20.0 * torch.log10(s)
    return score.to(x.dtype)


def reference_peak(y: torch.Tensor) -> torch.Tensor:
    """Per-item maximum of a ``(B, C, H, W)`` reference as ``(B, 1, 1, 1)``; 1 where the reference is all zero."""
    m = y.flatten(1).amax(dim=1) if y.shape[0] else y.new_zeros(0)
    return torch.where(m > 0, m, torch.ones_like(m)).view(-1, 1, 1, 1)


def log_relative(z: torch.Tensor, m: torch.Tensor, eps: float) -> torch.Tensor:
    """``log2(z / m + eps)``: log radiance in stops relative to the reference peak ``m``, floored by ``eps``."""
    return torch.log2(z / m + eps)


def check_eps(eps: object) -> float:
    eps = check_real(eps, "eps", positive=True, high=1.0, what="in (0, 1)")
    if eps == 1.0:
        raise ValueError(f"eps must be in (0, 1); got {eps}")
    return eps


def nonnegative_pair(x: object, y: object) -> tuple[torch.Tensor, torch.Tensor]:
    xb, yb = image_pair(x, y, ("x", "y"))
    check_nonnegative(xb, "x")
    check_nonnegative(yb, "y")
    if xb.shape[0] and xb[0].numel() == 0:
        raise ValueError(f"x and y must have at least one value per image; got shape {tuple(xb.shape[1:])}")
    return float_pair(xb, yb)
