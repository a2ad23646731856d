"""A folder of computed tensors (simulated systems) keyed by a fingerprint of the code and values
that made them.

The folder is ``MSAM_CACHE_DIR`` when set (empty: no cache), else the user's cache folder
(:func:`platformdirs.user_cache_dir`). A key fingerprints functions by their bytecode, constants,
closed-over values and the global functions and constants they read (recursively), so an edited
system or excitation misses the cache instead of reading a stale result; the torch version is part
of every key. Files are written whole
(a temporary file renamed into place); a folder that cannot be written or a file that cannot be
read costs only the computation.
"""
from __future__ import annotations

import dataclasses
import hashlib
import os
import tempfile
import types
from pathlib import Path
from typing import Any, Callable

import torch

_MEMORY: dict[str, Any] = {}


def folder() -> Path | None:
    """The cache folder, or None when ``MSAM_CACHE_DIR`` is set empty."""
    chosen = os.environ.get("MSAM_CACHE_DIR")
    if chosen is None:
        from platformdirs import user_cache_dir

        return Path(user_cache_dir("msam-torch"))
    return Path(chosen) if chosen else None


def fingerprint(*values: Any) -> str:
    """A hex digest of ``values``: functions by code and closure, dataclasses by field, containers by item."""
    digest = hashlib.sha256(torch.__version__.encode())
    _feed(digest, values, set())
    return digest.hexdigest()


def cached(compute: Callable[[], torch.Tensor], *key: Any) -> torch.Tensor:
    """``compute()``, or a copy of its earlier result for the same ``key`` (this process, then the folder)."""
    name = fingerprint(*key)
    if name in _MEMORY:
        return _MEMORY[name].clone()
    where = folder()
    path = where / f"{name}.pt" if where else None
    value = None
    if path is not None and path.is_file():
        try:
            value = torch.load(path, weights_only=True)
        except Exception:  # an unreadable file costs the computation only
            value = None
    if value is None:
        value = compute()
        if path is not None:
            _write(path, value)
    _MEMORY[name] = value
    return value.clone()


def _write(path: Path, value: Any) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=path.parent, suffix=".part")
        with os.fdopen(handle, "wb") as stream:
            torch.save(value, stream)
        os.replace(temporary, path)
    except OSError:
        pass


def _names(code: types.CodeType) -> list[str]:
    """The global names ``code`` and the code objects nested in it read."""
    nested = [c for c in code.co_consts if isinstance(c, types.CodeType)]
    return [*code.co_names, *(n for c in nested for n in _names(c))]


def _feed(digest, value: Any, seen: set) -> None:
    if isinstance(value, types.FunctionType):
        if id(value) in seen:
            return
        seen.add(id(value))
        _feed(digest, value.__code__, seen)
        _feed(digest, tuple(c.cell_contents for c in value.__closure__ or ()), seen)
        used = [value.__globals__.get(n) for n in _names(value.__code__)]
        _feed(digest, [g for g in used if isinstance(g, (types.FunctionType, int, float, str, tuple))], seen)
    elif isinstance(value, types.CodeType):
        digest.update(value.co_code)
        _feed(digest, (value.co_consts, value.co_names), seen)
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        _feed(digest, (type(value).__qualname__, *(getattr(value, f.name) for f in dataclasses.fields(value))), seen)
    elif hasattr(value, "items"):  # a mapping
        _feed(digest, tuple(sorted(((str(k), v) for k, v in value.items()), key=lambda kv: kv[0])), seen)
    elif isinstance(value, (tuple, list)):
        digest.update(f"{type(value).__name__}{len(value)}(".encode())
        for item in value:
            _feed(digest, item, seen)
        digest.update(b")")
    elif torch.is_tensor(value):
        digest.update(repr((value.dtype, tuple(value.shape))).encode() + value.detach().cpu().numpy().tobytes())
    else:
        digest.update(f"{type(value).__name__}:{value!r};".encode())
