"""Reading radiance files: :func:`load_radiance`, the one way radiance maps are read.

The command line's jobs (:mod:`torch_modulo.pipeline`), :class:`torch_modulo.data.HDRFolder` and the demo read
radiance through it, with one policy for values a radiance map cannot hold:

- **Negative values** (lossy compression and sensor processing leave small ones) are clamped to 0, always.
- **Display-referred files** (8/16-bit PNG and TIFF, the integers of a photo, sRGB-encoded for a screen) are not
  radiance. ``linear=False`` refuses them, naming the file; ``linear=True`` is the caller saying their integers are
  linear (a raw camera export); the default, None, reads them as stored. ``torch-modulo simulate`` refuses them
  unless given ``--linear``.
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
from torch_modulo.io import integer_sample_bits, read_image

__all__ = ["NONFINITE", "RADIANCE_EXTENSIONS", "display_referred", "load_radiance"]

#: Radiance files the folder commands ``simulate`` and ``tonemap`` read.
RADIANCE_EXTENSIONS = (".exr", ".hdr", ".pfm", ".tif", ".tiff")
#: What :func:`load_radiance` does with NaN and infinite values.
NONFINITE = ("replace", "raise")

_CHANNELS = (None, 1, 3, "auto")


def display_referred(path: str | os.PathLike[str]) -> str | None:
    """What makes an image file display-referred rather than radiance: its integer samples (``"8-bit integers"``),
    or None for a float file (EXR, HDR, PFM, float TIFF). Only the header is read.

    Raises:
        FileNotFoundError, OSError: the file cannot be opened (the message names it).

    Example:
        >>> import tempfile
        >>> from torch_modulo.io import write_image
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     png = write_image(os.path.join(folder, "x.png"), torch.zeros(1, 2, 2), dtype="uint8")
        ...     exr = write_image(os.path.join(folder, "x.exr"), torch.zeros(1, 2, 2))
        ...     display_referred(png), display_referred(exr)
        ('8-bit integers', None)
    """
    bits = integer_sample_bits(path)
    return f"{bits}-bit integers" if bits else None


def _refuse_display_referred(path: str | os.PathLike[str]) -> None:
    what = display_referred(path)
    if what is not None:
        raise ValueError(
            f"{path} holds {what}, display-referred values (a photo encoded for a screen, not radiance): it would be "
            "captured as if its encoded values were light. Give a linear radiance file (EXR, HDR, PFM or float "
            "TIFF), or, if its integers are linear (a raw camera export), say so: linear=True (torch-modulo "
            "simulate --linear)"
        )


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
    linear: bool | None = None,
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
        linear: what integer (8/16-bit, display-referred) files are: ``False`` refuses them (:func:`display_referred`
            names what the file holds), ``True`` reads their integers as linear radiance, None (default) reads them
            as stored, without an opinion.

    Returns:
        The radiance, or ``(radiance, counts)`` with ``with_counts=True``.

    Raises:
        FileNotFoundError, OSError: the file cannot be read (the message names it).
        ValueError: NaN or infinite values with ``nonfinite="raise"``, no finite value at all, no channels, an
            integer file with ``linear=False``, or a bad argument.
        TypeError: ``with_counts`` is not a bool, or ``linear`` not a bool or None.

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
    if linear is not None and not isinstance(linear, bool):
        raise TypeError(f"linear must be a bool or None; got {linear!r} ({type(linear).__name__})")
    if linear is False:
        _refuse_display_referred(path)
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
