"""Handing freed memory back to the system between the stages of large work."""

from __future__ import annotations

import functools


def give_back_freed_memory() -> None:
    """Return the heap's free pages to the system, where the C library allows it (glibc).

    glibc keeps freed blocks of between 128 kB and 32 MB (a slab's masks and
    labels, a million-vertex surface's index arrays) in its heap, where the
    next stage's larger arrays cannot use them, and the process's resident
    memory counts them. Called between stages, after their big frees;
    elsewhere (no glibc) a no-op. Changes no result.
    """
    trim = _malloc_trim()
    if trim is not None:
        trim(0)


@functools.cache
def _malloc_trim():
    import ctypes
    import ctypes.util

    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or None).malloc_trim
    except (OSError, AttributeError, TypeError):
        return None
