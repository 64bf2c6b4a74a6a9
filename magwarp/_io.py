"""Safe loading of policy and checkpoint files: no pickled code runs unless the caller trusts the file.

``torch.load(..., weights_only=False)`` unpickles arbitrary Python objects, and unpickling can run any code (a
``__reduce__`` payload). Everything magwarp loads goes through here:

* :func:`load_module` — a policy: TorchScript first (its archive holds no pickled Python code), else a
  ``torch.save``d file read with ``weights_only=True`` (tensors, state dicts, plain containers);
* :func:`load_checkpoint_file` — a training checkpoint (``weights_only=True``; checkpoints hold only tensors and
  plain data).

A file that needs the full unpickler (e.g. a whole ``torch.save``d ``nn.Module``) is refused with
:class:`UnsafeFileError` unless ``trusted=True`` (the command's ``--trust``), which loads it the old way after a
warning that says why.
"""

from __future__ import annotations

import os
import pickle
import re
import struct
import warnings
import zipfile
from typing import Any

__all__ = ["UnsafeFileError", "UnreadableFileError", "load_module", "load_checkpoint_file", "safe_torch_load"]


class UnreadableFileError(ValueError):
    """The file is not a policy or checkpoint magwarp can read (corrupt, text, another format)."""


class UnsafeFileError(UnreadableFileError):
    """The file holds pickled Python objects whose loading could run code; load it only if trusted."""


TRUST_HINT = "load it only if you trust its source: --trust on the command line, trusted=True in Python"


def _trusted_load(path: str, map_location, what: str):
    import torch

    warnings.warn(f"loading {what} {path!r} with the full unpickler (trusted): this runs any code pickled in the "
                  f"file; do this only for files from a source you trust", UserWarning, stacklevel=3)
    return torch.load(path, map_location=map_location, weights_only=False)


def safe_torch_load(path: str, map_location="cpu", *, trusted: bool = False, what: str = "file") -> Any:
    """``torch.load`` of ``path`` with ``weights_only=True``; with ``trusted``, the full unpickler (and a warning)
    where the safe one refuses. Raises :class:`UnsafeFileError` for pickled code, :class:`UnreadableFileError` for a
    file torch cannot read at all."""
    import torch

    try:
        return torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as e:
        text = str(e)
        if "Weights only load failed" not in text:
            raise UnreadableFileError(f"{what} {path!r} is not a torch file magwarp can read "
                                      f"({_first_line(text)})") from None
        if trusted:
            try:
                return _trusted_load(path, map_location, what)
            except _READ_ERRORS as e2:
                _reraise_unreadable(e2, path, what)
        found = re.search(r"GLOBAL ([\w.]+)", text)
        if found is None:  # not a pickle of objects at all (a text file, a truncated stream)
            detail = re.search(r"WeightsUnpickler error: \s*([^\n]+)", text)
            raise UnreadableFileError(f"{what} {path!r} is not a torch file magwarp can read"
                                      f"{f' ({detail.group(1).strip()})' if detail else ''}") from None
        raise UnsafeFileError(f"refusing to load {what} {path!r}: it holds pickled Python objects (e.g. "
                              f"{found.group(1)}) that could run code when loaded; {TRUST_HINT}") from None
    except _READ_ERRORS as e:
        _reraise_unreadable(e, path, what)


#: what torch.load raises on a file that is not what it expects; random bytes reach the unpickler's internals too
#: (an empty stack, a short struct, a length beyond memory), so those count as unreadable as well
_READ_ERRORS = (RuntimeError, EOFError, ValueError, zipfile.BadZipFile, OSError, UnicodeDecodeError, LookupError,
                pickle.UnpicklingError, AttributeError, ImportError, TypeError, struct.error, OverflowError,
                MemoryError)


def _reraise_unreadable(e: BaseException, path: str, what: str):
    if isinstance(e, (FileNotFoundError, IsADirectoryError, PermissionError, UnreadableFileError)):
        raise e
    raise UnreadableFileError(f"{what} {path!r} is not a torch file magwarp can read "
                              f"({type(e).__name__}: {_first_line(str(e))})") from None


def _first_line(text: str) -> str:
    line = text.strip().splitlines()[0] if text.strip() else "empty message"
    return line[:200]


def _is_torchscript(path: str) -> bool:
    """TorchScript archives are zip files with a ``constants.pkl`` or ``code/`` entry (``torch.save`` files are not)."""
    try:
        with zipfile.ZipFile(path) as z:
            return any(n.endswith("/constants.pkl") or "/code/" in n for n in z.namelist())
    except (zipfile.BadZipFile, OSError):
        return False


def load_module(path: str, map_location="cpu", *, trusted: bool = False):
    """A policy module from ``path``: TorchScript (safe), else a ``torch.save``d object loaded with
    ``weights_only=True`` (a whole pickled ``nn.Module`` needs ``trusted``). Returns what the file holds."""
    import torch

    if not os.path.exists(path):
        raise FileNotFoundError(f"no policy file at {path!r}")
    if _is_torchscript(path):
        try:
            return torch.jit.load(path, map_location=map_location)
        except (RuntimeError, ValueError) as e:
            raise UnreadableFileError(f"policy file {path!r} is a broken TorchScript archive "
                                      f"({_first_line(str(e))})") from None
    return safe_torch_load(path, map_location, trusted=trusted, what="policy file")


def load_checkpoint_file(path: str, map_location="cpu", *, trusted: bool = False) -> dict:
    """A training checkpoint (a dict) from ``path``, without running pickled code unless ``trusted``."""
    state = safe_torch_load(path, map_location, trusted=trusted, what="checkpoint")
    if not isinstance(state, dict):
        raise UnreadableFileError(f"checkpoint {path!r} holds a {type(state).__name__}, not a magwarp training "
                                  f"checkpoint (a dict)")
    return state
