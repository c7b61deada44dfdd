"""Data pipelines: a Dataset of HDR radiance maps, and a Kornia augmentation that simulates a modulo capture.

:class:`HDRFolder` reads EXR/HDR/PFM/TIFF files (those the command line reads) with OpenImageIO inside
``__getitem__`` (it holds only paths), so it works with ``DataLoader(num_workers=...)``; with ``skip_bad=True`` a bad
file is skipped and reported instead of stopping the DataLoader. :class:`RandomModuloCapture` is an
:class:`~kornia.augmentation.IntensityAugmentationBase2D`: it draws one exposure per sample and returns the modulus
image (Eq. 1), optionally through the sensor noise model, inside ``AugmentationSequential`` or a DataLoader.

Example (a training batch of modulus images and the radiance they came from)::

    dataset = HDRFolder("scenes/", resize=512, crop=256, random_crop=True, normalize=255.0)
    loader = DataLoader(dataset, batch_size=8, num_workers=2, shuffle=True)
    capture = RandomModuloCapture(exposure=(1.0, 64.0), bits=8)
    for radiance in loader:
        moduli = capture(radiance)                                       # (B, C, H, W) integers in [0, 256)
        counts = torch.floor(radiance * capture.exposure.view(-1, 1, 1, 1))  # the unwrapping target
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from kornia.augmentation import IntensityAugmentationBase2D
from torch.utils.data import Dataset

from torch_modulo._checks import check_bits, check_choice, check_flag
from torch_modulo.capture import capture_modulo
from torch_modulo.radiance import NONFINITE, RADIANCE_EXTENSIONS, load_radiance
from torch_modulo.sensors.simulated import NoiseModel, simulate_capture

__all__ = ["HDR_EXTENSIONS", "HDRFolder", "RandomModuloCapture"]

#: Radiance map formats :class:`HDRFolder` collects: those the command line reads (EXR, HDR, PFM, TIFF).
HDR_EXTENSIONS = RADIANCE_EXTENSIONS


def _size(value: int | Sequence[int] | None, name: str) -> tuple[int, int] | None:
    if value is None:
        return None
    if isinstance(value, int) and not isinstance(value, bool):
        pair: tuple[Any, ...] = (value, value)
    elif isinstance(value, Sequence) and len(value) == 2:
        pair = tuple(value)
    else:
        raise TypeError(f"{name} must be an int or a pair (height, width); got {value!r}")
    if not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in pair):
        raise ValueError(f"{name} must hold positive ints; got {value!r}")
    return int(pair[0]), int(pair[1])


class HDRFolder(Dataset):
    """HDR radiance maps from a folder, as (C, H, W) float tensors >= 0.

    Each item is read with :func:`torch_modulo.radiance.load_radiance`, the reader the command line and the demo
    use: negative values (which lossy compression and sensor processing leave behind) become 0, and NaN and
    infinite values are replaced (NaN and -Inf by 0, +Inf by the image's largest finite value) or, with
    ``nonfinite="raise"``, refused with the file named. The item is given ``channels`` channels, optionally
    resized, scaled and cropped, then passed to ``transform``.

    Args:
        root: folder searched (recursively by default) for files with ``extensions``, in sorted path order; names
            that start with a dot are skipped at every level (``.ipynb_checkpoints``, a killed batch job's
            ``.<name>.tmp-*`` folders).
        extensions: file extensions to collect.
        recursive: search subfolders too.
        resize: None; an int: shrink so that the longer side is at most this (aspect kept; smaller images are
            left alone); or (height, width): resize to exactly that. Shrinking averages areas (no aliasing);
            growing interpolates bilinearly.
        crop: None, an int or (height, width): a centre crop, or a random crop with ``random_crop=True`` (drawn
            from torch's global generator, which DataLoader seeds per worker). Images smaller than the crop raise.
        random_crop: crop at a random position instead of the centre.
        channels: 3 (grey images are repeated, extra channels such as alpha dropped), 1 (luminance Y = 0.2126 R +
            0.7152 G + 0.0722 B of RGB images), or None (as stored).
        normalize: None, or a value: scale each image so that its 99.9th percentile equals this (images that are
            all zero stay zero). Useful to give scenes comparable ranges before a simulated capture.
        transform: callable applied last to the (C, H, W) tensor (for example a Kornia augmentation with
            ``keepdim=True``).
        return_path: items are ``(image, path string)`` instead of the image alone.
        dtype: floating dtype of the items (float16 and bfloat16 refuse, with the file named, an item whose
            radiance is beyond their range instead of turning it into infinities: use ``normalize``).
        nonfinite: ``"replace"`` (default) or ``"raise"``: what reading an item does with NaN and infinite
            values. A file with no finite value at all is refused either way.
        linear: take integer (8/16-bit TIFF or PNG) files as linear radiance; by default they are refused, naming
            the file, since their values are display-referred (see :func:`torch_modulo.radiance.load_radiance`).
        skip_bad: an item that cannot be read or shaped (an unreadable file, NaN refused, smaller than the crop,
            a display-referred file) is skipped instead of raising: a warning names the file and the error, the
            next good item (in path order, wrapping around) is given in its place, and :attr:`skipped` maps each
            skipped file to its error (per process: each DataLoader worker keeps its own). An epoch then holds
            some items twice; all files failing raises.

    Raises:
        FileNotFoundError: ``root`` does not exist.
        ValueError: no files found, bad sizes or options; when reading an item, an image smaller than the crop, NaN
            or infinite values it may not replace (the message names the file and counts them), or radiance beyond
            ``dtype``'s range.
        TypeError: a flag (``recursive``, ``random_crop``, ``return_path``, ``linear``, ``skip_bad``) that is not a
            bool.
        OSError: an item cannot be read (the message names the file).

    Example:
        >>> import tempfile
        >>> from torch_modulo.io import write_image
        >>> with tempfile.TemporaryDirectory() as root:
        ...     _ = write_image(os.path.join(root, "a.exr"), torch.rand(3, 40, 60) * 100)
        ...     dataset = HDRFolder(root, resize=30, crop=16)
        ...     len(dataset), tuple(dataset[0].shape)
        (1, (3, 16, 16))
    """

    def __init__(
        self,
        root: str | os.PathLike[str],
        *,
        extensions: Sequence[str] = HDR_EXTENSIONS,
        recursive: bool = True,
        resize: int | Sequence[int] | None = None,
        crop: int | Sequence[int] | None = None,
        random_crop: bool = False,
        channels: int | None = 3,
        normalize: float | None = None,
        transform: Callable[[torch.Tensor], Any] | None = None,
        return_path: bool = False,
        dtype: torch.dtype = torch.float32,
        nonfinite: str = "replace",
        linear: bool = False,
        skip_bad: bool = False,
    ) -> None:
        root = Path(root)
        if not root.is_dir():
            raise FileNotFoundError(2, "HDR folder not found", str(root))
        if isinstance(extensions, str):
            extensions = (extensions,)
        exts = tuple(e.lower() if e.startswith(".") else f".{e.lower()}" for e in extensions)
        recursive = check_flag(recursive, "recursive")
        pattern = root.rglob("*") if recursive else root.glob("*")
        # Hidden names are skipped at every level: .ipynb_checkpoints, and a killed batch job's .<name>.tmp-* folders.
        self.paths: list[Path] = sorted(
            p
            for p in pattern
            if p.is_file()
            and p.suffix.lower() in exts
            and not any(part.startswith(".") for part in p.relative_to(root).parts)
        )
        if not self.paths:
            raise ValueError(f"no files ending in {', '.join(exts)} in {root}" + (" or its subfolders" * recursive))
        self.root = root
        self.resize: int | tuple[int, int] | None
        if isinstance(resize, int) and not isinstance(resize, bool):
            if resize < 1:
                raise ValueError(f"resize must be positive; got {resize}")
            self.resize = resize
        else:
            self.resize = _size(resize, "resize")
        self.crop = _size(crop, "crop")
        self.random_crop = check_flag(random_crop, "random_crop")
        if channels not in (None, 1, 3):
            raise ValueError(f"channels must be 1, 3 or None; got {channels!r}")
        self.channels = channels
        if normalize is not None:
            if isinstance(normalize, bool) or not isinstance(normalize, int | float) or not normalize > 0:
                raise ValueError(f"normalize must be a positive number or None; got {normalize!r}")
            if not math.isfinite(normalize):
                raise ValueError(f"normalize must be finite; got {normalize}")
        self.normalize = normalize
        if transform is not None and not callable(transform):
            raise TypeError(f"transform must be callable; got {type(transform).__name__}")
        self.transform = transform
        self.return_path = check_flag(return_path, "return_path")
        if dtype not in (torch.float16, torch.bfloat16, torch.float32, torch.float64):
            raise TypeError(f"dtype must be a floating torch dtype; got {dtype}")
        self.dtype = dtype
        self.nonfinite = check_choice(nonfinite, "nonfinite", NONFINITE)
        self.extensions = exts
        self.linear = check_flag(linear, "linear")
        self.skip_bad = check_flag(skip_bad, "skip_bad")
        #: Files skipped with ``skip_bad`` (in this process), each with its error.
        self.skipped: dict[str, str] = {}

    def __len__(self) -> int:
        return len(self.paths)

    def load(self, index: int) -> torch.Tensor:
        """Read item ``index`` before resizing, scaling and cropping: a (C, H, W) float32 radiance map >= 0."""
        image = load_radiance(self.paths[index], channels=self.channels, nonfinite=self.nonfinite, linear=self.linear)
        assert isinstance(image, torch.Tensor)
        return image

    def _resized(self, image: torch.Tensor) -> torch.Tensor:
        if self.resize is None:
            return image
        h, w = image.shape[-2:]
        if isinstance(self.resize, int):
            scale = self.resize / max(h, w)
            if scale >= 1:
                return image
            size = (max(1, round(h * scale)), max(1, round(w * scale)))
        else:
            size = self.resize
        if size == (h, w):
            return image
        if size[0] <= h and size[1] <= w:
            out = F.interpolate(image[None], size=size, mode="area")
        else:
            out = F.interpolate(image[None], size=size, mode="bilinear", align_corners=False, antialias=True)
        return out[0].clamp_(min=0.0)

    def _cropped(self, image: torch.Tensor, path: Path) -> torch.Tensor:
        if self.crop is None:
            return image
        ch, cw = self.crop
        h, w = image.shape[-2:]
        if ch > h or cw > w:
            raise ValueError(f"{path} is {h}x{w} after resizing, smaller than the crop {ch}x{cw}")
        if self.random_crop:
            top = int(torch.randint(0, h - ch + 1, ()))
            left = int(torch.randint(0, w - cw + 1, ()))
        else:
            top, left = (h - ch) // 2, (w - cw) // 2
        return image[:, top : top + ch, left : left + cw].contiguous()

    def __getitem__(self, index: int) -> Any:
        if not -len(self) <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} files")
        index %= len(self)
        if not self.skip_bad:
            image = self._item(index)
        else:
            image, index = self._first_good(index)
        if self.transform is not None:
            image = self.transform(image)
        return (image, str(self.paths[index])) if self.return_path else image

    def _first_good(self, index: int) -> tuple[torch.Tensor, int]:
        """Item ``index``, or the next that loads (``skip_bad``), and its index."""
        failed: list[str] = []
        for step in range(len(self)):
            n = (index + step) % len(self)
            try:
                image = self._item(n)
            except (OSError, ValueError) as error:
                self.skipped[str(self.paths[n])] = reason = f"{type(error).__name__}: {error}"
                failed.append(f"{self.paths[n]} ({reason})")
                continue
            for skipped in failed:
                warnings.warn(f"HDRFolder: skipped {skipped}; gave {self.paths[n]} in its place", stacklevel=3)
            return image, n
        raise ValueError(f"every file of {self.root} failed to load; the last: {failed[-1]}")

    def _item(self, index: int) -> torch.Tensor:
        """Item ``index`` read, resized, scaled and cropped, in the dataset's dtype (before ``transform``)."""
        path = self.paths[index]
        image = self._resized(self.load(index))
        if self.normalize is not None:
            flat = image.flatten()
            k = max(1, min(flat.numel(), math.ceil(0.999 * flat.numel())))
            peak = float(flat.kthvalue(k).values) if flat.numel() else 0.0
            if peak > 0:
                image = image * (self.normalize / peak)
        image = self._cropped(image, path)
        if image.numel() and self.dtype in (torch.float16, torch.bfloat16):
            top, limit = float(image.max()), torch.finfo(self.dtype).max
            if top > limit:
                raise ValueError(
                    f"{path}: radiance reaches {top:.6g}, beyond the largest {self.dtype} ({limit:.6g}); "
                    "scale it with normalize= or load it as float32"
                )
        return image.to(self.dtype)

    def __repr__(self) -> str:
        return f"HDRFolder({str(self.root)!r}, {len(self)} files, resize={self.resize}, crop={self.crop})"


class RandomModuloCapture(IntensityAugmentationBase2D):
    r"""Simulate a modulo capture with a random exposure per sample: :math:`I_m = \mathrm{mod}(\lfloor \tau E
    \rfloor, 2^N)` (Eq. 1), or the noisy sensor of :func:`torch_modulo.sensors.simulate_capture`.

    The input is radiance (any non-negative range: nothing is clamped to [0, 1]); the output holds integers in
    ``[0, 2**bits)``. Every sample is captured (there is no ``p``: a batch mixing radiance and moduli would mean
    nothing). The exposures drawn by the last call are in ``self.exposure`` (also ``self._params["exposure"]``),
    which gives the unwrapping target ``floor(radiance * exposure)`` in counts. They are drawn in the
    augmentation's dtype (``.to(dtype)`` changes it; float32 by default) and applied in the input's dtype.

    Args:
        exposure: ``(low, high)`` range of exposures, or one float for a fixed exposure.
        bits: counter bit depth ``N``.
        log_uniform: draw ``log(tau)`` uniformly (equal odds per stop, the default) rather than ``tau``.
        noise: None for the noise-free capture, or a :class:`~torch_modulo.sensors.NoiseModel` (noise drawn from
            torch's global generator; a fixed-pattern gain, if any, is drawn afresh per call).
        straight_through: let gradients pass through the floor (see :func:`~torch_modulo.capture_modulo`);
            noise-free only.
        same_on_batch: one exposure for the whole batch.
        keepdim: keep a (C, H, W) input's shape.

    Shape:
        - Input: (C, H, W) or (B, C, H, W) radiance.
        - Output: (B, C, H, W) (or the input's shape with ``keepdim=True``).

    Example:
        >>> _ = torch.manual_seed(0)
        >>> aug = RandomModuloCapture(exposure=(1.0, 16.0), bits=8)
        >>> radiance = torch.full((2, 1, 2, 2), 100.0)
        >>> moduli = aug(radiance)
        >>> torch.equal(moduli, torch.floor(radiance * aug.exposure.view(-1, 1, 1, 1)) % 256)
        True
    """

    def __init__(
        self,
        exposure: float | tuple[float, float] = (1.0, 256.0),
        bits: int = 8,
        *,
        log_uniform: bool = True,
        noise: NoiseModel | None = None,
        straight_through: bool = False,
        same_on_batch: bool = False,
        keepdim: bool = False,
    ) -> None:
        super().__init__(p=1.0, same_on_batch=same_on_batch, keepdim=keepdim)
        if isinstance(exposure, int | float) and not isinstance(exposure, bool):
            low = high = float(exposure)
        elif isinstance(exposure, Sequence) and len(exposure) == 2:
            low, high = (float(v) for v in exposure)
        else:
            raise TypeError(f"exposure must be a number or a pair (low, high); got {exposure!r}")
        if not (math.isfinite(low) and math.isfinite(high) and 0 < low <= high):
            raise ValueError(f"exposure range must satisfy 0 < low <= high (finite); got ({low}, {high})")
        if noise is not None and not isinstance(noise, NoiseModel):
            raise TypeError(f"noise must be a NoiseModel or None; got {type(noise).__name__}")
        straight_through = check_flag(straight_through, "straight_through")
        if straight_through and noise is not None:
            raise ValueError("straight_through=True needs noise=None (the noisy capture has no gradient)")
        self.low, self.high = low, high
        self.bits = check_bits(bits, torch.float64)
        self.log_uniform = check_flag(log_uniform, "log_uniform")
        self.noise = noise
        self.straight_through = straight_through

    def generate_parameters(self, batch_shape: tuple[int, ...]) -> dict[str, torch.Tensor]:
        n = 1 if self.same_on_batch else batch_shape[0]
        u = torch.rand(n, device=self.device, dtype=self.dtype)
        if self.log_uniform:
            tau = torch.exp(math.log(self.low) + u * (math.log(self.high) - math.log(self.low)))
        else:
            tau = self.low + u * (self.high - self.low)
        tau = tau.clamp(min=self.low, max=self.high)  # guard the end points against rounding
        return {"exposure": tau.expand(batch_shape[0]).clone()}

    def apply_transform(
        self,
        input: torch.Tensor,
        params: dict[str, torch.Tensor],
        flags: dict[str, Any],
        transform: torch.Tensor | None = None,
    ) -> torch.Tensor:
        tau = params["exposure"].to(device=input.device, dtype=input.dtype)
        if self.noise is None:
            return capture_modulo(input, tau, self.bits, straight_through=self.straight_through)
        return simulate_capture(input, tau.view(-1, 1), self.bits, self.noise)[:, 0]

    def forward(
        self, input: torch.Tensor, params: dict[str, torch.Tensor] | None = None, **kwargs: Any
    ) -> torch.Tensor:
        if input.dim() == 4 and input.shape[0] == 0 and params is None:  # an empty batch: nothing to draw or capture
            self._params = {"exposure": torch.empty(0)}
            return input.clone()
        return super().forward(input, params, **kwargs)

    @property
    def exposure(self) -> torch.Tensor | None:
        """The (B,) exposures drawn by the last call, or None before the first."""
        return self._params.get("exposure")

    def __repr__(self) -> str:
        return (
            f"RandomModuloCapture(exposure=({self.low}, {self.high}), bits={self.bits}, log_uniform={self.log_uniform}"
            f", noise={self.noise}, same_on_batch={self.same_on_batch})"
        )
