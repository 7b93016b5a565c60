"""Keep freed memory in the process while a loop allocates and frees the same few megabytes every iteration.

glibc's malloc hands memory at the top of its heap back to the system once more than its trim threshold lies free
there, and serves blocks above its mmap threshold by mmap; both thresholds move with the process's history (a
freed block larger than the mmap threshold raises both). A loop that makes and drops ~1 MB arrays per iteration (a
synthetic frame: the complex spectra of its layers, their inverse transforms) can land on the wrong side of that:
the heap top trimmed after every frame, grown again by the next and faulted in page by page. Measured with
``vibro synth`` on this project's 2-core machine: 8000 frames 1.67 million minor page faults, 7.8 s of system CPU of
15.5 s in all; with :func:`steady_heap` 26,800 faults, 5.1 of 12.4 s (the system time left is creating the frame
files); 20,000 frames 44.7 -> 26.3 CPU-s. Python's own small objects are not affected (pymalloc). Imports nothing
heavy.
"""

from __future__ import annotations

import ctypes
import ctypes.util

#: glibc mallopt parameters (malloc.h)
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
#: free bytes kept at the heap's top before they go back to the system
TRIM_THRESHOLD_BYTES = 256 << 20
#: blocks from this size up are mmapped (glibc's largest allowed value on 64-bit: 32 MiB)
MMAP_THRESHOLD_BYTES = 32 << 20


def steady_heap(trim_bytes: int = TRIM_THRESHOLD_BYTES, mmap_bytes: int = MMAP_THRESHOLD_BYTES) -> bool:
    """Fix glibc's trim and mmap thresholds (bytes) for the rest of this process, so that they no longer move with
    what it freed. True when both were set; False where the C library is not glibc (nothing changes)."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, int(mmap_bytes))) and bool(mallopt(M_TRIM_THRESHOLD, int(trim_bytes)))
