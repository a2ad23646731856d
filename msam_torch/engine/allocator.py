"""The C allocator setting under which the engine's CPU chunks run fast.

A step's tensors are a few MiB each (``protocol.MAX_ELEMENTS`` values per chunk). glibc serves
blocks that size by ``mmap`` and hands them back to the kernel when they are freed, so each new
tensor page-faults its memory in again; on the Table 4 protocol that costs more than the
arithmetic (about 2500 page faults and 60 % of a 27-candidate varpro step). Raising glibc's mmap
and trim thresholds keeps freed blocks in the heap for the next tensor. The command-line tool and
the experiments call :func:`keep_freed_memory` at start; a Python program may call it too. It
changes nothing but speed, and it is a no-op off glibc.
"""
from __future__ import annotations

import ctypes

M_TRIM_THRESHOLD = -1  # mallopt parameters, from glibc's malloc.h
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 32 * 2**20  # glibc's largest allowed value on 64-bit systems
TRIM_THRESHOLD = 256 * 2**20


def keep_freed_memory() -> bool:
    """Serve blocks below 32 MiB from the heap and keep up to 256 MiB of freed heap in the
    process. Returns whether the C library accepted both settings."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (AttributeError, OSError):  # not glibc (macOS, Windows)
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))
