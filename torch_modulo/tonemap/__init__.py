"""Tone mapping: HDR radiance to display values in ``[0, 1]``.

The paper shows its recovered radiance maps "tone-mapped with the method in [20]" (Sec. 1, Fig. 1) and calls it
"a tone mapping scheme by adaptive histogram equalization [20]" (Sec. 6.1.1): [20] is Larson, Rushmeier and
Piatko, "A Visibility Matching Tone Reproduction Operator for High Dynamic Range Scenes", IEEE TVCG 3(4), 1997.
This module implements that operator (:func:`tonemap_histogram`) and the operators PyTorch users usually compare
it with:

==========================  ===========================================================  ==========
function / module           operator                                                     kind
==========================  ===========================================================  ==========
``tonemap_histogram``       Larson et al. 1997 histogram adjustment, linear ceiling      global
``tonemap_reinhard``        Reinhard et al. 2002 photographic operator (global form)      global
``tonemap_gamma``           exposure and gamma, per channel                              global
``tonemap_log``             logarithmic mapping ``log(1 + qL) / log(1 + k L_max)``       global
``tonemap_clahe``           CLAHE on log luminance (``kornia.enhance.equalize_clahe``)   local
==========================  ===========================================================  ==========

Conventions shared by every operator:

- Input: linear, non-negative radiance, ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``, with ``C = 1`` (grey) or
  ``C = 3`` (linear Rec.709 / sRGB primaries). Luminance is ``Y = 0.2126 R + 0.7152 G + 0.0722 B``. Negative,
  NaN or infinite values, other channel counts and other ranks raise ``ValueError``; non-floating input raises
  ``TypeError``. The absolute scale of the radiance does not matter except where an operator says so (the
  ``exposure`` of the gamma and logarithmic mappings, and Reinhard's ``delta``, an offset in radiance units that
  matters once the luminance is not far above it: scale radiance of about ``1e-5`` up, or lower ``delta``).
- Output: display-referred values in ``[0, 1]``, same shape, dtype and device as the input; linear display
  values unless ``srgb=True``, which applies the sRGB transfer function (``kornia.color.linear_rgb_to_rgb``).
- Statistics (log average, maximum, histogram, percentiles) are computed per batch item: a batch gives the
  same result as its images one at a time.
- Colour: the luminance-based operators (histogram, Reinhard, logarithmic, CLAHE) map luminance and scale R, G
  and B by the same factor ``Y_display / Y``, so colour ratios are kept wherever no channel exceeds 1 (channels
  are clipped to ``[0, 1]`` last, as a display would). The gamma mapping works per channel, as display
  encodings do, and does not keep ratios.
- Monotonic: for a fixed colour, a brighter input never gives a darker output. The global operators are
  monotonic over the whole image; CLAHE is monotonic at each pixel position (a blend of monotonic tile
  curves) but, being local, not between positions.

Gradients:
    The global operators are differentiable almost everywhere, including through their statistics (log
    average, maximum, the histogram's range and ceiling). Histogram bin counts are piecewise constant, so
    their derivative is 0 almost everywhere, and the ceiling loop's stopping decision is discrete. CLAHE is
    differentiable only with ``differentiable=True`` (Kornia's slow path); its default path quantises to 256
    levels and passes no gradient through the equalisation curve.

Speed:
    On the CPU without autograd the global operators read the batch once for their statistics (the histogram
    operator reads it through adaptive average pooling), then map it chunk by chunk through cache-sized scratch
    buffers with in-place arithmetic and one write of the output; each operation on a chunk runs on PyTorch's
    intra-op threads. With autograd, or on other devices, the same formulas run as ordinary whole-tensor
    operations. CLAHE always runs through Kornia.

Files: one per operator family (``histogram.py``, ``reinhard.py``, ``gamma.py``, ``log.py``, ``clahe.py``), and
``_common.py`` for what they share; every public name is importable from ``torch_modulo.tonemap``.
"""

from __future__ import annotations

from torch_modulo.tonemap._common import REC709_LUMA, luminance
from torch_modulo.tonemap.clahe import ClaheToneMap, tonemap_clahe
from torch_modulo.tonemap.gamma import GammaToneMap, tonemap_gamma
from torch_modulo.tonemap.histogram import HistogramToneMap, fovea_shape, tonemap_histogram
from torch_modulo.tonemap.log import LogToneMap, tonemap_log
from torch_modulo.tonemap.reinhard import ReinhardToneMap, tonemap_reinhard

__all__ = [
    "REC709_LUMA",
    "ClaheToneMap",
    "GammaToneMap",
    "HistogramToneMap",
    "LogToneMap",
    "ReinhardToneMap",
    "fovea_shape",
    "luminance",
    "tonemap_clahe",
    "tonemap_gamma",
    "tonemap_histogram",
    "tonemap_log",
    "tonemap_reinhard",
]
