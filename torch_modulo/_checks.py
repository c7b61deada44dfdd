"""Input validation shared by every operation.

Errors are the standard ``TypeError`` (wrong kind of object) and ``ValueError`` (right kind, bad value), and
every message names the argument and the offending value, e.g.
``"modulus must hold integers in [0, 256) for bits=8; got max 300.0"``.

(Kornia's ``KORNIA_CHECK`` raises ``kornia.core.exceptions.BaseError``, which is not a ``ValueError`` in the
Kornia release this project uses, so the checks are written here.)

Validation switch:
    The checks that read a tensor's values (:func:`check_finite`, :func:`check_nonnegative`, the value pass of
    :func:`check_modulus`, the positivity of :func:`exposure_tensor`, and the library's other value checks
    built on them) cost a reduction pass and a host sync each, and break a ``torch.compile`` graph. They are on
    by default; :func:`validation` (a context manager and decorator) or :func:`set_validation` switch them off in
    the current thread and context only, as ``torch.no_grad`` does: the setting is a :class:`contextvars.ContextVar`,
    so other threads, and asyncio tasks started before the switch, keep their own. Under ``torch.compile`` the
    layers take whole-tensor paths, so with the checks off they trace in one graph and
    ``torch.compile(layer, fullgraph=True)`` works (the capture layers, the multi-exposure unwrap and the global tone
    maps). With validation off, invalid input (negative or non-finite radiance, moduli outside ``[0, 2**bits)``,
    non-positive exposures) is no longer refused and gives undefined results. Checks of Python arguments, dtypes
    and shapes cost nothing and stay on.

Tensors on the ``meta`` device hold no values: the value checks refuse them with a ``ValueError`` that names the
device (with validation off they are not read, so shape-only work such as the capture still runs on them).
"""

from __future__ import annotations

import contextvars
import math
import numbers
from collections.abc import Collection, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

import torch

__all__ = [
    "MAX_BITS",
    "all_integers",
    "check_bits",
    "check_choice",
    "check_flag",
    "check_int",
    "check_real",
    "check_finite",
    "check_floating",
    "check_has_values",
    "check_image_shape",
    "check_modulus",
    "check_nonnegative",
    "check_tensor",
    "exposure_tensor",
    "is_channels_last",
    "like_memory_format",
    "nonnegative_max",
    "set_validation",
    "validation",
    "validation_enabled",
]

# The setting of the current thread and context (eager code only: while torch.compile traces, the value checks are
# off, see validation_enabled).
_VALIDATION: contextvars.ContextVar[bool] = contextvars.ContextVar("torch_modulo_validation", default=True)


def validation_enabled() -> bool:
    """Whether the value checks are on: the setting of the current thread and context (on by default; see
    :func:`validation`), and always off while ``torch.compile`` traces.

    The value checks read tensor values, which would break a compiled graph, so compiled code skips them by itself:
    ``torch.compile(layer, fullgraph=True)`` works without :func:`validation`. Types, shapes and arguments are still
    checked there; eager calls check values as the setting says.

    Example:
        >>> validation_enabled()
        True
    """
    if torch.compiler.is_compiling():
        return False
    return _VALIDATION.get()


def set_validation(enabled: bool) -> bool:
    """Switch the value checks on or off in the current thread and context, and return the previous setting there.

    It sets the :class:`contextvars.ContextVar` that :func:`validation_enabled` reads: the setting holds in the
    calling thread (other threads keep theirs; a new thread starts with the checks on) and in the current context
    (an asyncio task changes its own copy; tasks started afterwards inherit it), until it is set again. Nothing
    restores it: prefer the :func:`validation` context manager, which restores the previous setting on exit.

    Args:
        enabled: ``True`` to check tensor values (the default), ``False`` to skip those checks.

    Returns:
        The setting of the current thread and context before the call.

    Raises:
        TypeError: ``enabled`` is not a bool.

    Example:
        >>> previous = set_validation(False)
        >>> validation_enabled()
        False
        >>> _ = set_validation(previous)
    """
    enabled = check_flag(enabled, "enabled")
    previous = _VALIDATION.get()
    _VALIDATION.set(enabled)
    return previous


@contextmanager
def validation(enabled: bool) -> Iterator[None]:
    """Context manager (and decorator) that switches the value checks on or off, restoring them on exit.

    The checks that read tensor values (non-negative, finite radiance; moduli that are integers in
    ``[0, 2**bits)``; positive exposures) each cost a pass over the data and a host sync. Inside
    ``validation(False)`` they are skipped; invalid input then gives undefined results instead of an error. Like
    ``torch.no_grad``, the setting belongs to the current thread and context (see :func:`set_validation`): a
    ``validation(False)`` in one thread or asyncio task leaves the checks of the others on. Compiled code needs no
    switch: while ``torch.compile`` traces, the value checks are off (:func:`validation_enabled`), so
    ``torch.compile(layer, fullgraph=True)`` works as it is; check values eagerly where the inputs are not trusted.

    Args:
        enabled: ``False`` to skip the value checks, ``True`` to force them on.

    Raises:
        TypeError: ``enabled`` is not a bool.

    Example:
        >>> x = torch.tensor([-1.0, 2.0])
        >>> check_nonnegative(x, "radiance")
        Traceback (most recent call last):
        ...
        ValueError: radiance must be >= 0; got min -1.0
        >>> with validation(False):
        ...     check_nonnegative(x, "radiance")
        tensor([-1.,  2.])
    """
    enabled = check_flag(enabled, "enabled")
    token = _VALIDATION.set(enabled)
    try:
        yield
    finally:
        try:
            _VALIDATION.reset(token)
        except (ValueError, RuntimeError):  # exited in another context than it entered: restore the value itself
            _VALIDATION.set(token.old_value if token.old_value is not contextvars.Token.MISSING else True)


def is_channels_last(image: torch.Tensor) -> bool:
    """Whether a (B, C, H, W) tensor's images are stored channels last (``torch.channels_last``): the channels of a
    pixel adjacent in memory, and not also in the default layout (one channel, or one pixel, is both).

    Example:
        >>> x = torch.zeros(2, 3, 4, 4)
        >>> is_channels_last(x), is_channels_last(x.contiguous(memory_format=torch.channels_last))
        (False, True)
    """
    if image.dim() != 4 or image.shape[0] == 0:
        return False
    first = image[0]
    return not first.is_contiguous() and first.permute(1, 2, 0).is_contiguous()


def like_memory_format(out: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """``out`` in the memory format of ``like`` (the input it was computed from): channels last when ``like``'s images
    are (:func:`is_channels_last`) and ``out`` is 4-D, else ``out`` as it is."""
    if out.dim() == 4 and is_channels_last(like):
        return out.contiguous(memory_format=torch.channels_last)
    return out


def check_has_values(x: torch.Tensor, name: str) -> torch.Tensor:
    """Raise ``ValueError`` if ``x`` is on the ``meta`` device, which holds no values to read; return ``x``.

    Example:
        >>> check_has_values(torch.zeros(2, device="meta"), "radiance")
        Traceback (most recent call last):
        ...
        ValueError: radiance is on the meta device, which holds no values; got a meta tensor of shape (2,)
    """
    if x.device.type == "meta":
        raise ValueError(
            f"{name} is on the meta device, which holds no values; got a meta tensor of shape {tuple(x.shape)}"
        )
    return x


#: Largest bit depth whose integers (up to 2**bits) each floating dtype holds exactly.
MAX_BITS: dict[torch.dtype, int] = {
    torch.float16: 11,
    torch.bfloat16: 8,
    torch.float32: 24,
    torch.float64: 53,
}


def check_int(
    value: object, name: str, low: int | None = None, high: int | None = None, *, what: str | None = None
) -> int:
    """Return ``value`` as ``int`` if it is an integer (not a bool) in ``[low, high]``; else raise.

    Args:
        value: the argument to check.
        name: its name, for the message.
        low: smallest allowed value (inclusive), or ``None``.
        high: largest allowed value (inclusive), or ``None``.
        what: the requirement as the message should state it (``"an odd positive integer"``); by default the
            message names the bound that failed.

    Raises:
        TypeError: ``value`` is not an integer (floats, strings and bools are refused).
        ValueError: ``value`` is below ``low`` or above ``high``.

    Example:
        >>> check_int(3, "bins", 2)
        3
        >>> check_int(1, "bins", 2)
        Traceback (most recent call last):
        ...
        ValueError: bins must be >= 2; got 1
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an integer; got {value!r}")
    value = int(value)
    if low is not None and value < low:
        raise ValueError(f"{name} must be {what or f'>= {low}'}; got {value}")
    if high is not None and value > high:
        raise ValueError(f"{name} must be {what or f'<= {high}'}; got {value}")
    return value


def check_real(
    value: object,
    name: str,
    low: float | None = None,
    *,
    positive: bool = False,
    high: float | None = None,
    allow_inf: bool = False,
    what: str | None = None,
) -> float:
    """Return ``value`` as ``float`` if it is a real number (not a bool) within the bounds; else raise.

    Args:
        value: the argument to check.
        name: its name, for the message.
        low: smallest allowed value (inclusive), or ``None``.
        positive: require ``value > 0``.
        high: largest allowed value (inclusive), or ``None``.
        allow_inf: accept ``+inf`` (NaN is always refused).
        what: the requirement as every ``ValueError`` message should state it (``"a positive finite number"``,
            ``"in (0, 100]"``); by default the message names the condition that failed.

    Raises:
        TypeError: ``value`` is not a real number.
        ValueError: NaN, infinite (unless allowed) or out of bounds.

    Example:
        >>> check_real(0.0, "gamma", positive=True)
        Traceback (most recent call last):
        ...
        ValueError: gamma must be finite and > 0; got 0.0
        >>> check_real(2, "gamma", positive=True)
        2.0
        >>> check_real(0.0, "gamma", positive=True, what="a positive finite number")
        Traceback (most recent call last):
        ...
        ValueError: gamma must be a positive finite number; got 0.0
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a number; got {value!r}")
    value = float(value)

    def fail(requirement: str) -> ValueError:
        return ValueError(f"{name} must be {what or requirement}; got {value}")

    # Comparisons rather than math.isnan / math.isinf: torch.compile traces them on symbolic floats too.
    is_nan = value != value
    bad_inf = abs(value) == math.inf and not (allow_inf and value > 0)
    if low is not None and (is_nan or bad_inf or value < low):
        raise fail(f"finite and >= {low:g}")
    if positive and (is_nan or bad_inf or value <= 0):
        raise fail("finite and > 0")
    if is_nan or bad_inf:
        raise fail("finite")
    if high is not None and value > high:
        raise fail(f"<= {high:g}")
    return value


def check_flag(value: object, name: str) -> bool:
    """Return ``value`` as ``bool`` if it is a bool (Python or NumPy); refuse truthy stand-ins like ``"no"``."""
    if isinstance(value, bool):
        return value
    if type(value).__module__ == "numpy" and type(value).__name__ in ("bool", "bool_"):
        return bool(value)
    raise TypeError(f"{name} must be a bool; got {value!r}")


def check_choice(value: Any, name: str, choices: Collection[Any], *, what: str | None = None) -> Any:
    """Return ``value`` if it is one of ``choices``; unhashable or unknown values get a ``ValueError`` naming both.

    ``what`` replaces the list of choices in the message (``"'little' or 'big'"``).

    Example:
        >>> check_choice("png", "format", ("exr", "png"))
        'png'
        >>> check_choice("jpg", "format", ("exr", "png"))
        Traceback (most recent call last):
        ...
        ValueError: format must be one of 'exr', 'png'; got 'jpg'
    """
    try:
        ok = value in choices
    except TypeError:
        ok = False
    if isinstance(value, bool) and not any(isinstance(c, bool) for c in choices):
        ok = False  # True == 1: a flag is not a number
    if not ok:
        shown = what or "one of " + ", ".join(repr(c) for c in sorted(choices, key=repr))
        raise ValueError(f"{name} must be {shown}; got {value!r}")
    return value


def check_tensor(x: object, name: str) -> torch.Tensor:
    """Raise ``TypeError`` unless ``x`` is a tensor; return it."""
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor; got {type(x).__name__}")
    return x


def check_floating(x: object, name: str) -> torch.Tensor:
    """Raise ``TypeError`` unless ``x`` is a floating-point tensor; return it."""
    x = check_tensor(x, name)
    if not x.is_floating_point():
        raise TypeError(f"{name} must be a floating-point tensor; got dtype {x.dtype} (convert with .float())")
    return x


def check_bits(bits: object, dtype: torch.dtype = torch.float32) -> int:
    """Validate a sensor bit depth for values stored in ``dtype`` and return it as ``int``.

    A modulus of ``bits`` bits is held exactly by ``dtype`` only while ``2**bits`` is representable without
    rounding: 24 bits in float32, 53 in float64, 11 in float16, 8 in bfloat16.
    """
    if isinstance(bits, bool) or not isinstance(bits, numbers.Integral | torch.SymInt):  # numpy integers too
        if isinstance(bits, float) and bits.is_integer():
            bits = int(bits)
        else:
            raise TypeError(f"bits must be an integer; got {bits!r}")
    bits = int(bits)
    if bits < 1:
        raise ValueError(f"bits must be >= 1; got {bits}")
    limit = MAX_BITS.get(dtype)
    if limit is not None and bits > limit:
        wider = " (use float64)" if dtype != torch.float64 else ""
        raise ValueError(f"bits={bits} exceeds what {dtype} represents exactly (at most {limit} bits){wider}")
    return bits


def check_finite(x: torch.Tensor, name: str) -> torch.Tensor:
    """Raise ``ValueError`` if ``x`` holds NaN or infinity; the message counts them.

    One reduction pass (NaN and Inf propagate into the extremes); the counting passes run only on failure. A no-op
    with :func:`validation` off; a tensor on the ``meta`` device is refused (:func:`check_has_values`).
    """
    if validation_enabled() and x.numel() and x.is_floating_point():
        values = check_has_values(x, name).detach()
        lo, hi = torch.aminmax(values)
        if not (math.isfinite(float(lo)) and math.isfinite(float(hi))):
            n_nan = int(torch.isnan(values).sum())
            n_inf = int(torch.isinf(values).sum())
            raise ValueError(f"{name} must be finite; got {n_nan} NaN and {n_inf} Inf values")
    return x


def check_nonnegative(x: torch.Tensor, name: str) -> torch.Tensor:
    """Raise ``ValueError`` if ``x`` is not finite or holds negative values (one reduction pass when valid).

    A no-op with :func:`validation` off; a tensor on the ``meta`` device is refused (:func:`check_has_values`).
    """
    if validation_enabled():
        nonnegative_max(x, name)
    return x


def nonnegative_max(x: torch.Tensor, name: str) -> float:
    """Validate ``x`` as :func:`check_nonnegative` does and return its largest value (0.0 when empty).

    With :func:`validation` off it only returns the largest value (NaN propagates; negatives are not refused). It
    reads a value either way, so a tensor on the ``meta`` device is refused either way (:func:`check_has_values`).

    Example:
        >>> nonnegative_max(torch.tensor([0.5, 3.0]), "radiance")
        3.0
    """
    if not x.numel():
        return 0.0
    values = check_has_values(x, name).detach()
    if not validation_enabled():
        return float(values.max())
    lo, hi = torch.aminmax(values)
    lo_f, hi_f = float(lo), float(hi)
    if not (math.isfinite(lo_f) and math.isfinite(hi_f)):
        check_finite(x, name)
    if lo_f < 0:
        raise ValueError(f"{name} must be >= 0; got min {lo_f}")
    return hi_f


def check_modulus(modulus: torch.Tensor, bits: int, name: str = "modulus") -> torch.Tensor:
    """Validate a modulus image: a floating tensor of integers in ``[0, 2**bits)``.

    One fused pass computes the extremes and the integrality test; the slow diagnostic passes run only when
    something is wrong. With :func:`validation` off only the dtype and ``bits`` are checked. The values are read
    detached (no autograd warning for a modulus that requires grad); a modulus on the ``meta`` device is refused
    (:func:`check_has_values`).
    """
    check_floating(modulus, name)
    check_bits(bits, modulus.dtype)
    if not validation_enabled() or modulus.numel() == 0:
        return modulus
    values = check_has_values(modulus, name).detach()
    lo, hi = torch.aminmax(values)
    lo_f, hi_f = float(lo), float(hi)
    if not (math.isfinite(lo_f) and math.isfinite(hi_f)):
        check_finite(values, name)
    period = 2**bits
    if lo_f < 0 or hi_f >= period:
        raise ValueError(f"{name} must hold integers in [0, {period}) for bits={bits}; got min {lo_f}, max {hi_f}")
    if not all_integers(values, name=name):
        frac = values - torch.floor(values)
        bad = values.flatten()[int(frac.flatten().argmax())]
        raise ValueError(f"{name} must hold integers for bits={bits}; got non-integer value {float(bad)}")
    return modulus


def all_integers(x: torch.Tensor, chunk: int = 1 << 16, *, name: str = "tensor") -> bool:
    """True when every value of ``x`` is an integer; on the CPU it compares cache-sized chunks of ``chunk`` elements
    with one scratch buffer. A tensor on the ``meta`` device (named ``name``) is refused, whatever the validation
    switch (:func:`check_has_values`)."""
    x = check_has_values(x, name).detach()
    if not x.is_floating_point():
        return True
    if x.device.type != "cpu" or x.numel() <= chunk:
        return bool(torch.equal(x, torch.floor(x)))
    flat = x.reshape(-1)
    scratch = torch.empty(chunk, dtype=x.dtype)
    for start in range(0, flat.numel(), chunk):
        part = flat[start : start + chunk]
        if not torch.equal(torch.floor(part, out=scratch[: part.numel()]), part):
            return False
    return True


def check_image_shape(x: torch.Tensor, name: str, min_dims: int = 2, max_dims: int = 4) -> torch.Tensor:
    """Raise ``ValueError`` unless ``x`` has between ``min_dims`` and ``max_dims`` dimensions."""
    if not min_dims <= x.dim() <= max_dims:
        shapes = {2: "(H, W)", 3: "(C, H, W)", 4: "(B, C, H, W)", 5: "(B, M, C, H, W)"}
        allowed = " or ".join(shapes[d] for d in range(max_dims, min_dims - 1, -1) if d in shapes)
        raise ValueError(f"{name} must have shape {allowed}; got {tuple(x.shape)}")
    return x


def check_nonempty_image(x: torch.Tensor, name: str) -> torch.Tensor:
    """Raise ``ValueError`` if ``x``'s images have no pixels (height or width 0); an empty batch is fine."""
    if x.shape[-2] == 0 or x.shape[-1] == 0:
        raise ValueError(f"{name} must not be an empty image; got shape {tuple(x.shape)}")
    return x


#: The integer dtypes whose tensors :func:`exposure_tensor` takes as real numbers, as it takes Python ints.
_INTEGER_DTYPES = frozenset(
    d
    for d in (
        torch.uint8,
        torch.int8,
        torch.int16,
        torch.int32,
        torch.int64,
        getattr(torch, "uint16", None),
        getattr(torch, "uint32", None),
        getattr(torch, "uint64", None),
    )
    if d is not None
)


def _is_flag_or_text(value: object) -> bool:
    """True for what is not a number though Python or torch would convert it to one: bools and strings."""
    if isinstance(value, bool | str | bytes | bytearray):
        return True
    if type(value).__module__ == "numpy" and type(value).__name__ in ("bool", "bool_", "str_", "bytes_"):
        return True
    return isinstance(value, torch.Tensor) and value.dtype == torch.bool


def _holds_flags_or_text(values: Sequence[object]) -> bool:
    """True when a (nested) sequence holds a bool or a string anywhere."""
    for value in values:
        if _is_flag_or_text(value):
            return True
        if isinstance(value, Sequence) and _holds_flags_or_text(value):
            return True
    return False


def exposure_tensor(
    exposure: float | Sequence[float] | torch.Tensor,
    like: torch.Tensor,
    name: str = "exposure",
) -> torch.Tensor:
    """Turn a positive finite exposure (a number, a sequence of numbers, a numpy array or a tensor) into a tensor on
    ``like``'s device and dtype.

    One rule for every form: exposures are real numbers. A bool or a string is refused as a scalar, inside a
    (nested) sequence and as a numpy array or tensor dtype, complex values too; integers are real numbers in every
    form (Python and numpy ints, numpy integer arrays, and tensors of any integer dtype, ``uint8`` included).

    With :func:`validation` off the values are not checked (the conversion is then traceable by ``torch.compile``).

    Raises:
        TypeError: ``exposure`` is not a number, sequence of numbers, numpy array or tensor of real numbers.
        ValueError: a value is not positive or not finite, or ``exposure`` is a tensor on the ``meta`` device
            (:func:`check_has_values`; with the checks off a meta ``exposure`` is fine for a meta ``like``).

    Example:
        >>> exposure_tensor(torch.tensor([1, 16], dtype=torch.uint8), torch.zeros(2))
        tensor([ 1., 16.])
        >>> exposure_tensor([1.0, True], torch.zeros(2), "exposures")
        Traceback (most recent call last):
        ...
        TypeError: exposures must hold real numbers, not bools or strings; got [1.0, True]
    """
    if isinstance(exposure, torch.Tensor):
        if not (exposure.is_floating_point() or exposure.dtype in _INTEGER_DTYPES):
            raise TypeError(f"{name} must hold real numbers; got dtype {exposure.dtype}")
        if like.device.type != "meta" or (validation_enabled() and exposure.numel()):
            check_has_values(exposure, name)  # its values are copied to ``like``'s device, or checked
        source = exposure
    elif _is_flag_or_text(exposure):
        raise TypeError(f"{name} must be a positive number or tensor; got {exposure!r}")
    elif isinstance(exposure, numbers.Real):  # int, float and numpy scalars
        source = torch.tensor(float(exposure), dtype=torch.float64)
    elif type(exposure).__module__ == "numpy" and hasattr(exposure, "__array__"):  # a numpy array: as a tensor
        try:
            array = torch.as_tensor(exposure)
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(f"{name} must hold real numbers; got {exposure!r}") from None
        return exposure_tensor(array, like, name)
    elif isinstance(exposure, Sequence):
        if _holds_flags_or_text(exposure):  # torch.tensor and float() would take True as 1.0 and "16" as 16.0
            raise TypeError(f"{name} must hold real numbers, not bools or strings; got {exposure!r}")
        try:  # nested sequences too: (B, M) exposures as a list of lists
            source = torch.tensor(exposure, dtype=torch.float64)
        except (TypeError, ValueError, RuntimeError):
            try:  # anything float() takes: Fraction, Decimal, one-element arrays and tensors
                source = torch.tensor([float(v) for v in exposure], dtype=torch.float64)
            except (TypeError, ValueError, RuntimeError):
                raise TypeError(
                    f"{name} must be a sequence of numbers (or of equal-length sequences of numbers); got {exposure!r}"
                ) from None
    else:
        raise TypeError(f"{name} must be a positive number, a sequence of numbers or a tensor; got {exposure!r}")
    source = source.to(dtype=like.dtype)
    if validation_enabled() and source.numel():
        # Checked where the values are (the CPU for Python numbers: also for a ``like`` on the meta device), in
        # ``like``'s dtype, which is what the operation uses (float16 turns 1e5 into inf).
        values = source.detach()
        finite = torch.isfinite(values)
        if not bool(finite.all()):
            raise ValueError(f"{name} must be finite; got {values[~finite].flatten()[0].item()}")
        lo = float(values.min())
        if lo <= 0:
            raise ValueError(f"{name} must be positive; got {lo}")
    return source.to(device=like.device)
