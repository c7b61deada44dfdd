"""Sensor design: how many frames a modulo sensor needs for a scene, the error they give, and what a conventional
sensor with the same noise needs for the same error.

:func:`design` answers the first question a sensor designer asks ("with a 10-bit modulo sensor at 16 electrons
per count, how many frames do I need for 20 stops, and what error do I get against a conventional sensor?"): the
noise-aware plan (:func:`~torch_modulo.plan_exposures`), its predicted error
(:func:`~torch_modulo.multishot.prediction.predict_modulo`), and the conventional plan with the fewest frames whose
predicted median error is as low (:func:`~torch_modulo.multishot.prediction.plan_conventional`), with its own
prediction. ``torch-modulo design`` prints it.

The predictions are models of the default decoders: the modulo one with spatial evidence, on a smooth scene (the
ramp), where neighbours agree; ``spatial=False`` plans and predicts for each pixel decoded alone, which needs 2 to
3 times the frames and is what a scene of fine texture throughout needs (docs/multishot.md). :func:`simulate_median`
checks a prediction against the library's own sensors and decoders on the same ramp of radiances (protocol D of the
benchmarks; as an image whose columns hold the radiances, so that neighbours exist), and :func:`plot` draws both
sensors' predicted relative error against radiance (matplotlib, the optional extra ``torch_modulo[plot]``).

"Stops" has one meaning here, as in :func:`~torch_modulo.plan_exposures`: the scene spans ``E_min`` to
``2**stops E_min``, where ``E_min`` reads one count at the longest exposure (1.0 here).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from torch_modulo._atomic import atomic_file
from torch_modulo.multishot import merge_intensity, plan_exposures, unwrap_multi
from torch_modulo.multishot.prediction import (
    Prediction,
    conventional_exposures,
    plan_conventional,
    predict_conventional,
    predict_modulo,
)
from torch_modulo.noise import PRESETS, NoiseModel, as_noise_model
from torch_modulo.sensors import SimulatedIntensitySensor, SimulatedModuloSensor

__all__ = [
    "RAMP_ROWS",
    "DesignAnswer",
    "agrees",
    "conventional_exposures",
    "design",
    "noise_label",
    "plot",
    "predict_conventional",
    "predict_modulo",
    "simulate_median",
]

#: A prediction agrees with simulation when within this share of the simulated median, or within ``_ABSOLUTE``.
_RELATIVE = 0.25
_ABSOLUTE = 0.002
#: The most frames a conventional plan is given (as :func:`~torch_modulo.multishot.prediction.plan_conventional`).
_MOST_FRAMES = 256
#: The rows of :func:`simulate_median`'s ramp for the decoder with spatial evidence (each column one radiance).
RAMP_ROWS = 64


@dataclass(frozen=True, eq=False)
class DesignAnswer:
    """A modulo plan, its predicted error, and the conventional plan with the same predicted median error.

    Attributes:
        bits: both sensors' bit depth.
        noise: their noise model.
        stops: the scene's dynamic range.
        modulo: the modulo sensor's plan and prediction.
        conventional: the conventional sensor's plan and prediction.
        conventional_reaches: whether the conventional plan's predicted median error is at most the modulo plan's;
            where no plan of up to 256 frames is, it is the 256-frame plan.
    """

    bits: int
    noise: NoiseModel
    stops: float
    modulo: Prediction
    conventional: Prediction
    conventional_reaches: bool

    def to_dict(self, grid: bool = False) -> dict[str, Any]:
        """One JSON-compatible object: the plans (``exposures``, ``conventional_exposures``), their frames, predicted
        median errors and gross shares, and with ``grid`` the per-radiance predictions."""
        out: dict[str, Any] = {
            "bits": self.bits,
            "noise": noise_label(self.noise),
            "stops": self.stops,
            "exposures": list(self.modulo.exposures),
            "frames": self.modulo.frames,
            "spatial": self.modulo.spatial,
            "modulo_median_error": self.modulo.median_error,
            "modulo_gross_share": self.modulo.gross_share,
            "conventional_exposures": list(self.conventional.exposures),
            "conventional_frames": self.conventional.frames,
            "conventional_median_error": self.conventional.median_error,
            "conventional_gross_share": self.conventional.gross_share,
            "conventional_reaches": self.conventional_reaches,
        }
        if grid:
            out["radiance"] = self.modulo.radiance.tolist()
            out["modulo_relative_error"] = self.modulo.relative_error.tolist()
            out["conventional_relative_error"] = self.conventional.relative_error.tolist()
        return out


def design(
    bits: int,
    noise: NoiseModel | str,
    stops: float,
    frames: int | None = None,
    sigmas: float = 3.0,
    longest_frames: int = 1,
    spatial: bool = True,
) -> DesignAnswer:
    """The modulo plan for ``stops`` stops (at most ``frames`` exposures, if given), its predicted error, and the
    conventional plan with the fewest frames whose predicted median error is at most the modulo plan's.

    Args:
        bits: the bit depth of both sensors.
        noise: their :class:`~torch_modulo.noise.NoiseModel` or a preset name.
        stops: the scene's dynamic range (``E_min`` reads one count at the longest exposure, 1.0).
        frames: a budget for the modulo plan (:func:`~torch_modulo.plan_exposures`'s ``frames``), or None for
            the default plan.
        sigmas: the modulo decoder's gate.
        longest_frames: how many frames of the modulo plan take its longest exposure (``plan_exposures``'s
            ``longest_frames``; the budget counts them).
        spatial: plan and predict for the modulo decoder with spatial evidence (the default); False: for each pixel
            decoded alone.

    Returns:
        A :class:`DesignAnswer`. Where no conventional plan of up to 256 frames is as good, its plan is the
        256-frame one and ``conventional_reaches`` is False.

    Raises:
        TypeError, ValueError: as :func:`~torch_modulo.plan_exposures` and :func:`plan_conventional` raise them.

    Example:
        >>> answer = design(10, "q16", 20)
        >>> answer.modulo.frames < answer.conventional.frames
        True
    """
    model = as_noise_model(noise)
    if model is None:
        raise ValueError("noise must be a NoiseModel or a preset name; got None")
    taus = plan_exposures(
        stops,
        bits,
        noise=model,
        sigmas=sigmas,
        longest=1.0,
        frames=frames,
        longest_frames=longest_frames,
        spatial=spatial,
    )
    modulo = predict_modulo(taus, bits, model, sigmas, stops, spatial=spatial)
    try:
        conventional = plan_conventional(stops, bits, model, shortest=taus[0], target_median=modulo.median_error)
        reaches = True
    except ValueError:  # not within 256 frames: the most frames considered
        conventional, reaches = conventional_exposures(taus[0], _MOST_FRAMES), False
    prediction = predict_conventional(conventional, bits, model, stops)
    return DesignAnswer(bits, model, float(stops), modulo, prediction, reaches)


def simulate_median(
    prediction: Prediction, bits: int, noise: NoiseModel | str, values: int = 200_000, seed: int = 0
) -> float:
    """The simulated median relative error of a prediction's plan on its own ramp: ``values`` log-uniform radiances
    over ``prediction.stops`` stops from ``1 / tau_max``, captured by the library's simulated sensor of
    ``prediction.sensor``'s kind and decoded by its decoder (``unwrap_multi(..., noise=, spatial=)`` as predicted,
    or ``merge_intensity(..., noise=)``), in float64. For the decoder with spatial evidence the ramp is an image of
    :data:`RAMP_ROWS` rows whose columns each hold one radiance (``values`` rounded up to whole columns).

    Example:
        >>> p = predict_modulo([1 / 64, 1 / 8, 1.0], 8, "q16", stops=12)
        >>> agrees(p.median_error, simulate_median(p, 8, "q16", values=20_000))
        True
    """
    model = as_noise_model(noise)
    if values < 1:
        raise ValueError(f"values must be >= 1; got {values}")
    taus = list(prediction.exposures)
    rows = RAMP_ROWS if prediction.spatial else 1
    columns = -(-values // rows)
    radiance = torch.exp2(torch.linspace(0.0, prediction.stops, columns, dtype=torch.float64)) / taus[-1]
    image = radiance.reshape(1, 1, 1, columns).expand(1, 1, rows, columns)
    radiance = image.reshape(-1)
    if prediction.sensor == "modulo":
        stack = SimulatedModuloSensor(bits, model, seed=seed)(image, taus)
        estimate = unwrap_multi(stack.moduli, stack.exposures, bits, noise=model, spatial=prediction.spatial)
    else:
        stack = SimulatedIntensitySensor(bits, model, seed=seed)(image, taus)
        estimate = merge_intensity(stack.frames, stack.exposures, bits, noise=model)
    return float(((estimate.reshape(-1) - radiance).abs() / radiance).median())


def agrees(predicted: float, simulated: float) -> bool:
    """Whether a predicted median error is within 25% of the simulated one, or within 0.002 absolute."""
    return abs(predicted - simulated) <= max(_RELATIVE * simulated, _ABSOLUTE)


def noise_label(noise: NoiseModel) -> str:
    """A preset's name where ``noise`` is one, else its fields in short (``q=16 e-/count, read 20 e-, ...``).

    Example:
        >>> noise_label(NoiseModel.preset("q16")), noise_label(NoiseModel(electrons_per_count=4.0, read_noise=2.0))
        ('q16', 'q=4 e-/count, read 2 e-')
    """
    for name, fields in PRESETS.items():
        if noise == NoiseModel(**fields):
            return name
    parts = [f"q={noise.electrons_per_count:g} e-/count", f"read {noise.read_noise:g} e-"]
    if noise.dark_current:
        parts.append(f"dark {noise.dark_current:g} e-/exposure")
    if noise.prnu:
        parts.append(f"prnu {noise.prnu:g}")
    if not noise.shot_noise:
        parts.append("no shot noise")
    return ", ".join(parts)


def plot(answer: DesignAnswer, path: str | Path) -> Path:
    """Write a figure of both sensors' predicted relative error (rms, per radiance) against radiance to ``path``
    (PNG, PDF or SVG, by its extension), atomically. Needs matplotlib (``pip install torch_modulo[plot]``).

    Returns:
        The path written.
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as error:  # pragma: no cover - depends on the environment
        raise ImportError("plot needs matplotlib: pip install 'torch_modulo[plot]'") from error
    path = Path(path)
    figure, axes = plt.subplots(figsize=(7.0, 4.2), dpi=120)
    for prediction, colour in ((answer.modulo, "tab:blue"), (answer.conventional, "tab:orange")):
        label = (
            f"{prediction.sensor}: {prediction.frames} frames, median {prediction.median_error:.3g}"
            f", gross {100 * prediction.gross_share:.2g}%"
        )
        axes.loglog(prediction.radiance.numpy(), prediction.relative_error.numpy(), color=colour, label=label)
    axes.set_xlabel("radiance (counts per unit exposure; the longest exposure is 1)")
    axes.set_ylabel("predicted relative error (rms)")
    axes.set_title(f"{answer.bits}-bit sensors, {noise_label(answer.noise)}, {answer.stops:g} stops")
    axes.grid(True, which="both", alpha=0.3)
    axes.legend(fontsize=8)
    figure.tight_layout()
    with atomic_file(path, keep_suffix=True) as temporary:
        figure.savefig(temporary, format=path.suffix.lstrip(".").lower() or "png")
    plt.close(figure)
    return path
