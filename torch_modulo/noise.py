r"""The noise model of a digital-pixel sensor, shared by the simulated sensors and the noise-aware decoders.

A digital pixel (DFPA, paper Sec. 3) integrates photo-current on a small capacitor; each time the capacitor reaches
its threshold charge ``q`` (electrons per count) it is discharged and a counter steps. Per pixel and exposure
``tau`` the collected charge is Poisson with mean :math:`\lambda = q\,\tau E g + D \tau` (radiance ``E`` in counts per
unit exposure, fixed-pattern gain ``g``, dark current ``D``), read/reset noise adds :math:`\sigma_r` electrons rms,
and the counter reads :math:`I = \max(\lfloor e / q \rfloor, 0)`.

In counts, a frame whose expected count is ``m`` (signal plus dark) then has the variance

.. math:: \operatorname{Var}(I) \approx m / q + (\sigma_r / q)^2 + 1/12,

and the mean :math:`\lambda / q - 1/2` (the ``1/12`` and ``1/2`` come from the counter's floor) once the charge
spreads over a few thresholds. :meth:`NoiseModel.count_variance` gives this variance; it is what the noise-aware
decoder (:func:`torch_modulo.unwrap_multi` with ``noise=``) and planner (:func:`torch_modulo.plan_exposures`) use.
The fixed-pattern gain is not frame-to-frame noise: it scales ``E`` the same way in every frame, so it does not
enter the decoding.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, ClassVar, overload

import torch

from torch_modulo._checks import check_choice, check_flag, check_real

__all__ = ["PRESETS", "NoiseModel", "as_noise_model"]

#: Named noise models (see :meth:`NoiseModel.preset`). Electrons per count ``q`` and read noise are in electrons.
PRESETS: dict[str, dict[str, Any]] = {
    # A photon-counting pixel: one electron per count and 1 e- rms read noise (the NoiseModel defaults).
    "photon-counting": {"electrons_per_count": 1.0, "read_noise": 1.0},
    # The same pixel with a 16-electron charge quantum and 16 e- read noise (one count of read noise).
    "q16": {"electrons_per_count": 16.0, "read_noise": 16.0},
    # A digital-pixel focal plane array of the kind the paper's camera used (MIT Lincoln Laboratory DFPA):
    # see NoiseModel.preset for the published figures behind these numbers and what is derived from them.
    "dfpa": {"electrons_per_count": 3000.0, "read_noise": 40.0, "dark_current": 0.0},
}


@dataclass(frozen=True)
class NoiseModel:
    """Noise of a digital-pixel sensor (see the module docstring for the equations).

    The default is a photon-counting pixel: photon shot noise with one electron per count (variance in counts =
    mean) and 1 electron rms read noise; no dark current, no fixed pattern. Named presets:
    :meth:`NoiseModel.preset`.

    Args:
        electrons_per_count: ``q``, the threshold charge that makes one counter pulse (the quantisation step), > 0.
            Larger values average shot noise down in counts: its variance is ``mean / q``.
        read_noise: ``sigma_r``, read/reset noise in electrons rms per frame, >= 0 (``read_noise / q`` counts).
        dark_current: ``D``, electrons per unit exposure, >= 0 (a dark frame collects ``D tau / q`` counts of
            charge on average; its read-out mean is about half a count lower, the counter's floor).
        prnu: ``sigma_g``, relative standard deviation of the fixed-pattern gain (0.01 = 1 %), >= 0.
        shot_noise: draw the collected charge from a Poisson distribution (True) or use its mean (False).

    Raises:
        TypeError: a parameter is not a number (or ``shot_noise`` not a bool).
        ValueError: a parameter is negative or not finite, ``electrons_per_count`` is 0, or the model's count
            variance (for counts up to ``2**53``) or dark counts per unit exposure are beyond float64's range.

    Example:
        >>> NoiseModel(read_noise=2.0).is_noiseless
        False
        >>> NoiseModel(shot_noise=False, read_noise=0.0).is_noiseless
        True
        >>> NoiseModel().count_variance(100.0)       # 100 counts of shot noise + 1 count of read noise + 1/12
        101.08333333333333
    """

    electrons_per_count: float = 1.0
    read_noise: float = 1.0
    dark_current: float = 0.0
    prnu: float = 0.0
    shot_noise: bool = True

    presets: ClassVar[tuple[str, ...]] = tuple(PRESETS)

    def __post_init__(self) -> None:
        q = check_real(self.electrons_per_count, "electrons_per_count", 0.0)
        if q == 0:
            raise ValueError("electrons_per_count must be > 0; got 0.0")
        object.__setattr__(self, "electrons_per_count", q)
        for name in ("read_noise", "dark_current", "prnu"):
            object.__setattr__(self, name, check_real(getattr(self, name), name, 0.0))
        check_flag(self.shot_noise, "shot_noise")
        object.__setattr__(self, "shot_noise", bool(self.shot_noise))
        # The decoders and the planner evaluate the count variance for counts up to a 53-bit counter's: refuse a
        # model whose variance (or dark counts) is beyond float64's range there, rather than overflow later.
        read = self.read_noise / q
        variance = 2.0**53 / q + read * read  # inf (not OverflowError) past float64's range
        if not (math.isfinite(variance) and math.isfinite(self.dark_counts)):
            raise ValueError(
                f"electrons_per_count={q!r} with read_noise={self.read_noise!r} and dark_current={self.dark_current!r} "
                "makes the count variance (counts / electrons_per_count + (read_noise / electrons_per_count)^2) or "
                "the dark counts (dark_current / electrons_per_count) overflow float64; use a larger "
                "electrons_per_count (or the model's values in other units)"
            )

    @classmethod
    def preset(cls, name: str) -> NoiseModel:
        """A named noise model.

        - ``"photon-counting"``: one electron per count, 1 e- rms read noise (the default ``NoiseModel()``).
        - ``"q16"``: 16 electrons per count and 16 e- read noise: the same pixel with a larger charge quantum.
        - ``"dfpa"``: a digital-pixel focal plane array like the paper's camera (MIT Lincoln Laboratory's DFPA:
          Tyrrell et al., IEEE Trans. Electron Devices 56(11), 2009: 256 x 256 pixels at 30 um pitch; Schultz et
          al., Lincoln Laboratory Journal 20(2), 2014: a 16-bit in-pixel counter). The pixel counts charge quanta
          set by an integration capacitance of about 1-10 fF (US patent 9,712,771); with a swing of about 0.5 V
          that is ``q = C dV / e`` of about 3,000-30,000 electrons per count, and the low end is used here
          (3,000). The only analogue noise left is the capacitor's reset (kTC) noise, about 40 e- rms at 10 fF
          and 300 K. The charge quantum and read noise are derived from those figures, not measured values.

        Raises:
            ValueError: an unknown name (the message lists the presets).

        Example:
            >>> NoiseModel.preset("photon-counting") == NoiseModel()
            True
        """
        check_choice(name, "noise preset", PRESETS)
        return cls(**PRESETS[name])

    @property
    def is_noiseless(self) -> bool:
        """True when every term is off: the sensor then reads ``floor(tau E)`` exactly."""
        return not self.shot_noise and self.read_noise == 0 and self.dark_current == 0 and self.prnu == 0

    @property
    def dark_counts(self) -> float:
        """Dark counts per unit exposure, ``D / q``."""
        return self.dark_current / self.electrons_per_count

    @overload
    def count_variance(self, counts: torch.Tensor) -> torch.Tensor: ...

    @overload
    def count_variance(self, counts: float) -> float: ...

    def count_variance(self, counts: float | torch.Tensor) -> float | torch.Tensor:
        """Variance, in counts squared, of a frame whose expected count (signal plus dark) is ``counts`` (>= 0).

        ``counts / q`` (shot noise, when on) ``+ (read_noise / q)**2 + 1/12`` (the counter's floor).
        """
        q = self.electrons_per_count
        floor = (self.read_noise / q) ** 2 + 1.0 / 12.0
        if not self.shot_noise:
            return counts * 0.0 + floor
        if isinstance(counts, torch.Tensor):
            return counts.clamp_min(0.0) / q + floor
        return max(float(counts), 0.0) / q + floor

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def as_noise_model(noise: object) -> NoiseModel | None:
    """A :class:`NoiseModel`, a preset name (converted with :meth:`NoiseModel.preset`) or None; refuse the rest.

    Example:
        >>> as_noise_model("q16").electrons_per_count
        16.0
    """
    if isinstance(noise, str):
        return NoiseModel.preset(noise)
    if noise is not None and not isinstance(noise, NoiseModel):
        raise TypeError(
            f"noise must be a NoiseModel or None; got {type(noise).__name__} (or name a preset: {', '.join(PRESETS)})"
        )
    return noise
