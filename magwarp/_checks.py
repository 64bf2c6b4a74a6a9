"""Input checks shared by the simulator, the envs and the command: counts, seeds, finite numbers, devices, Warp.

Every check raises a ``ValueError`` (or ``TypeError`` for a wrong kind of value) whose message names the argument
and the bad value, so that a user's mistake never surfaces as an internal error from numpy, torch or Warp.
"""

from __future__ import annotations

import math
import numbers
import os
import sys
import tempfile

import numpy as np

__all__ = ["MAGNITUDE_MAX", "check_magnitude", "as_count", "as_flag", "as_seed", "as_finite", "check_finite", "device_name", "warp_device", "init_warp",
           "stiffness_limit"]

#: the largest seed torch and numpy accept (unsigned 64-bit)
SEED_MAX = 2**64 - 1


#: counts are Warp launch sizes and array dimensions: int32
COUNT_MAX = 2**31 - 1


#: the largest limit, gain or noise level a model accepts (SI units): far beyond any maglev system (XPlanar: 2-4 m/s,
#: 10-50 m/s^2), and small enough that a step's float32 arithmetic (products with each other and with dt) stays finite
MAGNITUDE_MAX = 1e6


def check_magnitude(**values) -> None:
    """Refuse the first number whose magnitude exceeds :data:`MAGNITUDE_MAX` (None passes), naming it."""
    for name, value in values.items():
        if value is not None and abs(float(value)) > MAGNITUDE_MAX:
            raise ValueError(f"{name} must be at most {MAGNITUDE_MAX:g} in magnitude (a step's float32 arithmetic "
                             f"would overflow), got {value!r}")


def as_flag(value, name: str) -> bool:
    """``value`` as a ``bool``: True/False (numpy's too) or the integers 0 and 1; anything else (NaN, strings, 2) is a
    TypeError naming it, instead of Python's truthiness deciding."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)) and int(value) in (0, 1):
        return bool(value)
    raise TypeError(f"{name} must be True or False, got {value!r}")


def as_count(value, name: str, minimum: int = 1) -> int:
    """``value`` as an ``int`` in ``[minimum, 2**31 - 1]``; refuses bools, NaN, strings and non-integral numbers such
    as 2.5 (instead of truncating them), and counts beyond Warp's int32 sizes."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Real, np.integer, np.floating)):
        raise TypeError(f"{name} must be an integer >= {minimum}, got {value!r} ({type(value).__name__})")
    if isinstance(value, (float, np.floating)) and not (math.isfinite(value) and float(value).is_integer()):
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    count = int(value)
    if count < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value!r}")
    if count > COUNT_MAX:
        raise ValueError(f"{name} must be at most 2**31 - 1 (Warp's int32 sizes), got {value!r}")
    return count


def as_seed(value, name: str = "seed") -> int:
    """A seed as an ``int`` in ``[0, 2**64)`` (what torch's and numpy's generators take)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Integral, np.integer)):
        raise TypeError(f"{name} must be None or an integer in [0, 2**64), got {value!r} ({type(value).__name__})")
    if not 0 <= int(value) <= SEED_MAX:
        raise ValueError(f"{name} must be None or an integer in [0, 2**64), got {value!r}")
    return int(value)


def as_finite(value, name: str) -> float:
    """A real, finite number as a ``float`` (NaN, inf, strings and overflowing values are refused)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Real, np.integer, np.floating)):
        raise TypeError(f"{name} must be a finite number, got {value!r} ({type(value).__name__})")
    try:
        out = float(value)
    except OverflowError:
        raise ValueError(f"{name} must be a finite number, got {value!r}") from None
    if not math.isfinite(out):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return out


def check_finite(*, allow_none: tuple[str, ...] = (), vectors: tuple[str, ...] = (), **values) -> None:
    """Every keyword must be a number, finite in float32 (what the device stores); those named in ``vectors`` may be
    sequences of numbers, those in ``allow_none`` None (their default). Raises naming the first bad one."""
    for name, value in values.items():
        if value is None and name in allow_none:
            continue
        what = f"{name} must be a finite number{' (or numbers)' if name in vectors else ''}"
        if value is None or isinstance(value, (str, bytes, bool, np.bool_, dict)):
            raise TypeError(f"{what}, got {value!r}")
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            raise TypeError(f"{what}, got {value!r}") from None
        if arr.dtype == object or (arr.ndim and name not in vectors):
            raise TypeError(f"{what}, got {value!r}")
        with np.errstate(over="ignore", invalid="ignore"):
            stored = arr.astype(np.float32)
        if not np.all(np.isfinite(stored)):
            raise ValueError(f"{name} must be finite (in float32), got {value!r}")


def device_name(device) -> str | None:
    """A device as Warp's name: ``"cpu"``/``"cuda:N"`` strings, ``torch.device`` objects and Warp devices alike."""
    if device is None:
        return None
    if isinstance(device, str):
        return device
    if type(device).__module__.startswith("torch") and type(device).__name__ == "device":
        if device.type == "cuda":
            return f"cuda:{0 if device.index is None else device.index}"
        return device.type
    alias = getattr(device, "alias", None)  # a warp Device
    if isinstance(alias, str):
        return alias
    raise TypeError(f"device must be 'cpu', 'cuda:N', a torch.device or a warp device, got {device!r}")


def warp_device(device):
    """The Warp device for ``device`` (see :func:`device_name`; None: the first CUDA device, else the CPU), or a
    ValueError naming the devices this machine has."""
    import warp as wp

    init_warp()
    name = device_name(device)
    if name is None:
        name = "cuda:0" if wp.is_cuda_available() else "cpu"
    if name == "cuda" and wp.is_cuda_available():
        name = "cuda:0"
    available = ["cpu", *(str(d) for d in wp.get_cuda_devices())]
    if name not in available:
        raise ValueError(f"device {device!r} is not available here (devices: {', '.join(available)})")
    return wp.get_device(name)


_WARP_READY = False
_NO_DRIVER = "Warp CUDA warning: Could not find or load the NVIDIA CUDA driver"


def init_warp() -> None:
    """``wp.init()`` without the "could not find or load the NVIDIA CUDA driver" line that Warp's native code prints
    on every machine without a GPU (the normal case for a CPU user, not a warning). Anything else Warp writes to
    stderr during initialisation is passed through."""
    global _WARP_READY
    if _WARP_READY:
        return
    import warp as wp

    try:
        from warp._src import context
    except ImportError:  # another Warp layout: its runtime attribute moved
        context = getattr(wp, "context", None)
    if getattr(context, "runtime", None) is not None:
        _WARP_READY = True
        return
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no usable file descriptor 2 (embedded interpreters): initialise plainly
        wp.init()
        _WARP_READY = True
        return
    with tempfile.TemporaryFile(mode="w+b") as captured:
        os.dup2(captured.fileno(), 2)
        try:
            wp.init()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        captured.seek(0)
        text = captured.read().decode("utf-8", "replace")
    rest = "".join(line for line in text.splitlines(keepends=True) if not line.startswith(_NO_DRIVER))
    if rest:
        sys.stderr.write(rest)
    _WARP_READY = True


#: ``h * sqrt(K / M)`` below which the critically damped impedance law, integrated semi-implicitly with step ``h``,
#: is stable: the update's eigenvalues stay in the unit circle for ``a = h w < 2 (sqrt(2) - 1)`` (Jury's test on
#: ``x' = x + h v'``, ``v' = v - h (w^2 x + 2 w v)``).
STABLE_HW = 2.0 * (math.sqrt(2.0) - 1.0)


def stiffness_limit(inertia: float, dt: float) -> float:
    """The largest stable stiffness of the impedance law for mass (or moment of inertia) ``inertia`` at step ``dt``."""
    return float(inertia) * (STABLE_HW / float(dt)) ** 2
