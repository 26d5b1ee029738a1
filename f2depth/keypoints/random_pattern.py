"""DSO's random byte pattern: glibc ``srand(3141592)`` then ``rand() & 0xFF`` per entry.

glibc's ``rand()`` (TYPE_3, glibc's ``stdlib/random_r.c``) is an additive lagged-Fibonacci generator
seeded by a Lehmer generator; DSO seeds it in the ``PixelSelector`` constructor (``PixelSelector2.cpp``).
It is reimplemented here so that the pattern, and with it the selector's output, is the same on every
platform.
"""

from __future__ import annotations

import threading

import numpy as np

DSO_SEED = 3141592

_MOD31 = 2**31 - 1
_lock = threading.Lock()
_cache: dict[int, np.ndarray] = {}


def glibc_rand(seed: int, count: int) -> np.ndarray:
    """The first ``count`` outputs of glibc ``rand()`` after ``srand(seed)``, as int64 (each < 2³¹)."""
    if count < 0:
        raise ValueError(f"count must be >= 0, got {count}")
    r = [0] * 34
    r[0] = seed % 2**32
    if r[0] == 0:  # glibc replaces a zero seed by 1
        r[0] = 1
    # glibc works on int32: a seed >= 2^31 is negative there.
    state = r[0] - 2**32 if r[0] >= 2**31 else r[0]
    r[0] = state
    for i in range(1, 31):
        # Schrage's method as glibc does it, in signed 32-bit arithmetic.
        hi = abs(state) // 127773 * (1 if state >= 0 else -1)  # C division truncates toward zero
        lo = state - hi * 127773
        state = 16807 * lo - 2836 * hi
        if state < 0:
            state += _MOD31
        r[i] = state
    for i in range(31, 34):
        r[i] = r[i - 31]
    r = [v & 0xFFFFFFFF for v in r]
    total = 344 + count
    r.extend([0] * (total - 34))
    for i in range(34, total):
        r[i] = (r[i - 31] + r[i - 3]) & 0xFFFFFFFF
    return np.asarray(r[344:], dtype=np.int64) >> 1


def random_pattern(size: int, seed: int = DSO_SEED) -> np.ndarray:
    """``size`` bytes (uint8) of DSO's pattern ``rand() & 0xFF`` after ``srand(seed)``; cached, read-only."""
    with _lock:
        cached = _cache.get(seed)
        if cached is None or cached.size < size:
            grow = max(size, 2 * cached.size if cached is not None else 0, 640 * 480)
            cached = (glibc_rand(seed, grow) & 0xFF).astype(np.uint8)
            cached.setflags(write=False)
            _cache[seed] = cached
    return cached[:size]
