"""Reading radiance files: :func:`load_radiance`, the one way radiance maps are read.

The command line's jobs (:mod:`torch_modulo.pipeline`), :class:`torch_modulo.data.HDRFolder` and the demo read
radiance through it, with one policy for values a radiance map cannot hold:

- **Negative values** (lossy compression and sensor processing leave small ones) are clamped to 0, always.
- **NaN and infinite values** are replaced by default (``nonfinite="replace"``): NaN and -Inf by 0, +Inf by the
  largest finite value of the image (an overflowed pixel is at least as bright as the brightest one that did
  not overflow). ``nonfinite="raise"`` refuses such a file instead, naming it and how many of each it holds. A
  file with no finite value at all is refused either way: there is nothing to replace them with.

Example:
    >>> import tempfile
    >>> from torch_modulo.io import write_image
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     path = write_image(os.path.join(folder, "x.exr"), torch.tensor([[[1.0, -0.5], [float("inf"), 4.0]]]))
    ...     image, counts = load_radiance(path, with_counts=True)
    >>> image.tolist(), counts
    ([[[1.0, 0.0], [4.0, 4.0]]], {'nan': 0, 'posinf': 1, 'neginf': 0, 'negative': 1})
"""

from __future__ import annotations

import os

import torch

from torch_modulo._checks import check_choice, check_flag
from torch_modulo.io import read_image

__all__ = ["NONFINITE", "RADIANCE_EXTENSIONS", "load_radiance"]

#: Radiance files the folder commands ``simulate`` and ``tonemap`` read.
RADIANCE_EXTENSIONS = (".exr", ".hdr", ".pfm", ".tif", ".tiff")
#: What :func:`load_radiance` does with NaN and infinite values.
NONFINITE = ("replace", "raise")

_CHANNELS = (None, 1, 3, "auto")


def _used_channels(image: torch.Tensor, channels: int | str | None, source: object) -> torch.Tensor:
    """The channels the result is made of: all (None), or the first one or three."""
    c = image.shape[0]
    if c < 1:
        raise ValueError(f"{source} has no channels")
    if channels is None:
        return image
    return image[:3] if c >= 3 else image[:1]


def _shaped(image: torch.Tensor, channels: int | str | None) -> torch.Tensor:
    """Repeat grey into RGB (``channels=3``) or reduce RGB to luminance (``channels=1``)."""
    c = image.shape[0]
    if channels == 3 and c == 1:
        return image.expand(3, -1, -1).clone()
    if channels == 1 and c == 3:
        from torch_modulo.tonemap import REC709_LUMA

        weights = torch.tensor(REC709_LUMA, dtype=image.dtype).view(3, 1, 1)
        return (image * weights).sum(0, keepdim=True)
    return image


def load_radiance(
    path: str | os.PathLike[str],
    *,
    channels: int | str | None = "auto",
    nonfinite: str = "replace",
    dtype: torch.dtype = torch.float32,
    with_counts: bool = False,
) -> torch.Tensor | tuple[torch.Tensor, dict[str, int]]:
    """Read a radiance file as a (C, H, W) tensor of finite values >= 0 (the policy in the module docstring).

    Args:
        path: an EXR, HDR, PFM or float TIFF file (anything :func:`torch_modulo.io.read_image` reads).
        channels: ``"auto"`` (default): grey files give one channel, colour files their first three (alpha, the
            other views of a multi-view file and extra layers are dropped; of two channels, the first);
            ``3``: RGB (grey repeated); ``1``: luminance ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` (grey as is);
            ``None``: every channel as stored.
        nonfinite: ``"replace"`` (default) or ``"raise"``: what to do with NaN and infinite values.
        dtype: ``torch.float32`` (default) or ``torch.float64``.
        with_counts: also return how many values were replaced or clamped: ``{"nan", "posinf", "neginf",
            "negative"}``.

    Returns:
        The radiance, or ``(radiance, counts)`` with ``with_counts=True``.

    Raises:
        FileNotFoundError, OSError: the file cannot be read (the message names it).
        ValueError: NaN or infinite values with ``nonfinite="raise"``, no finite value at all, no channels, or a
            bad argument.

    Example:
        >>> import tempfile
        >>> from torch_modulo.io import write_image
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     path = write_image(os.path.join(folder, "x.exr"), torch.tensor([[[1.0, float("nan")]]]))
        ...     try:
        ...         load_radiance(path, nonfinite="raise")
        ...     except ValueError as error:
        ...         print(str(error).split(";")[0].replace(folder, "DIR"))
        DIR/x.exr holds 1 NaN or infinite value (1 NaN, 0 +Inf, 0 -Inf)
    """
    check_choice(channels, "channels", _CHANNELS, what="1, 3, 'auto' or None")
    check_choice(nonfinite, "nonfinite", NONFINITE)
    check_flag(with_counts, "with_counts")
    image = read_image(path, dtype=dtype)
    image = _used_channels(image, channels, path)
    counts = {
        "nan": int(torch.isnan(image).sum()),
        "posinf": int(torch.isposinf(image).sum()),
        "neginf": int(torch.isneginf(image).sum()),
    }
    bad = counts["nan"] + counts["posinf"] + counts["neginf"]
    if bad:
        what = f"({counts['nan']} NaN, {counts['posinf']} +Inf, {counts['neginf']} -Inf)"
        if bad == image.numel():
            raise ValueError(f"{path} holds no finite value {what}: nothing to replace them with")
        if nonfinite == "raise":
            raise ValueError(
                f"{path} holds {bad} NaN or infinite value{'s' * (bad > 1)} {what}; pass nonfinite='replace' to "
                "replace NaN and -Inf by 0 and +Inf by the largest finite value"
            )
        top = max(float(image[torch.isfinite(image)].max()), 0.0)
        image = torch.nan_to_num(image, nan=0.0, posinf=top, neginf=0.0)
    counts["negative"] = int((image < 0).sum())
    image = _shaped(image.clamp_min(0.0), channels)
    return (image, counts) if with_counts else image
