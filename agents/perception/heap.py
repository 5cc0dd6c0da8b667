"""Keep freed memory in the process heap between frames (glibc): no page faults on every frame.

Per frame the front end allocates and frees tens of arrays of 1-10 MB (ray samples, derivatives,
the blurred frame). glibc serves such sizes by ``mmap`` once its dynamic threshold stops growing
and returns freed heap tops to the system beyond 128 kB, so every frame faults the same pages in
again: on rendered table1 frames that was 4-8 ms of CPU (kernel time) per 1024 x 768 frame, a
quarter of detection, and it came and went with the other allocations of the process (the
OpenCV AprilTag path paid it, the sphere-model path mostly not). :func:`keep_freed_memory` sets
the mmap threshold to 64 MB and the trim threshold to 512 MB, so those arrays come from and go
back to the heap; the process then holds on to its peak heap size (a few tens of MB here) instead
of returning it. It is process-wide, idempotent, and a no-op where glibc's ``mallopt`` is absent.
"""

from __future__ import annotations

import ctypes
import ctypes.util

__all__ = ["keep_freed_memory"]

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_done: bool | None = None


def keep_freed_memory(mmap_threshold: int = 64 << 20, trim_threshold: int = 512 << 20) -> bool:
    """Ask glibc to keep arrays below ``mmap_threshold`` bytes in the heap and not to trim it.

    Returns True if the settings were applied (now or by an earlier call), False where the C
    library has no ``mallopt`` (not glibc) or refused them.
    """
    global _done
    if _done is not None:
        return _done
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        _done = False
        return _done
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    _done = bool(mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold))) and bool(mallopt(_M_TRIM_THRESHOLD, int(trim_threshold)))
    return _done
