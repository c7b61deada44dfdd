"""Noise-free rollover counting over an exposure stack (paper Sec. 5, Eqs. 6-7), as printed and robust.

Eqs. 6-7 as printed: sort by exposure ``tau``; ``E^(0) = 0``;

    k^(i) = floor(tau^(i) E^(i-1) / 2^N),    E^(i) = (k^(i) 2^N + I_m^(i)) / tau^(i).

Because ``E^(i-1)`` is the *lower* edge of a quantisation cell, the printed floor picks the wrong ``k`` on a large
share of pixels whenever the neighbouring exposure ratio ``r`` is not exactly ``2^N`` (about a third of the pixels
for 1:100:10000 at 8 bits, noise-free). ``method="robust"`` (the default) predicts the next count from the centre
of the previous cell and rounds against the observed modulus:

    k^(i) = round((r (I^(i-1) + 1/2) - 1/2 - I_m^(i)) / 2^N),    I^(i) = I_m^(i) + k^(i) 2^N,

which is exact, noise-free, for every ratio ``1 <= r <= 2^N - 1`` and for every integer ratio up to ``2^N``. (For a
non-integer ratio strictly between ``2^N - 1`` and ``2^N`` the counts behind one count of the shorter exposure span
up to ``2^N + 1`` values, so no rule can be exact there; such ratios are accepted and are right on all but a small
share of pixels.) Both return ``E = I^(M) / tau^(M)`` (Eq. 7's
convention: the lower edge of the final cell) or, with ``return_counts=True``, the integer counts ``I^(M)``.
"""

from __future__ import annotations

import torch

from torch_modulo._checks import check_finite, check_modulus
from torch_modulo._chunks import column_chunks

__all__ = ["METHODS", "count_rollovers"]

#: The noise-free decoding rules: the robust rule (default) and Eq. 6 as printed.
METHODS = ("robust", "paper")


def count_rollovers(
    frames: torch.Tensor,
    tau: torch.Tensor,
    ratios: torch.Tensor,
    bits: int,
    method: str,
    return_counts: bool,
    out: torch.Tensor,
) -> None:
    """Run Eqs. 6-7 (or the robust rule) chunk by chunk into ``out``, validating each chunk's moduli on the way.

    Args:
        frames: (B, M, n) moduli, exposures sorted ascending.
        tau: (B, M) float64 exposures.
        ratios: (B, M - 1) neighbouring ratios.
        bits: the bit depth ``N``.
        method: ``"robust"`` or ``"paper"``.
        return_counts: write the counts ``I^(M)`` instead of the radiance ``I^(M) / tau^(M)``.
        out: (B, n) output, the frames' dtype.
    """
    b, m, n = frames.shape
    period = float(2**bits)
    inv_p = 1.0 / period
    on_cpu = frames.device.type == "cpu"
    chunks = column_chunks(n, b) if on_cpu else [slice(0, n)]  # float64 work stays in cache on the CPU
    chunk = chunks[0].stop
    work = torch.float64 if (on_cpu or frames.device.type == "cuda") else frames.dtype
    scale = (ratios * inv_p).to(work).unsqueeze(-1)  # (B, M-1, 1): r / P
    tau_max = tau[:, -1:].to(work)
    counts = torch.empty((b, min(chunk, n)), dtype=work, device=frames.device)
    scratch = torch.empty((b, min(chunk, n)), dtype=frames.dtype, device=frames.device)
    bad = False
    for cols in chunks:
        width = cols.stop - cols.start
        acc, tmp = counts[:, :width], scratch[:, :width]
        for i in range(m):
            m_i = frames[:, i, cols]
            lo, hi = torch.aminmax(m_i)
            bad |= not (float(lo) >= 0.0 and float(hi) < period)  # NaN fails both comparisons
            bad |= not torch.equal(torch.floor(m_i, out=tmp), m_i)
            if i == 0:
                acc.copy_(m_i)
                continue
            s = scale[:, i - 1]
            if method == "robust":
                # k >= 0: under noise the rounding can ask for k = -1 on dark pixels; no counter runs backwards.
                acc.add_(0.5).mul_(s).sub_(m_i, alpha=inv_p).sub_(0.5 * inv_p).round_().clamp_min_(0.0)
            else:
                acc.mul_(s).floor_()
            torch.add(m_i, acc, alpha=period, out=acc)
        if return_counts:
            out[:, cols].copy_(acc)
        else:
            torch.div(acc, tau_max, out=acc)
            out[:, cols].copy_(acc)
    if bad:  # diagnose with the slow, precise checks
        check_finite(frames, "moduli")
        check_modulus(frames, bits, "moduli")
