"""Profiles grouped into blocks for the per-point work.

NumPy's speed on per-point arithmetic over millions of points is that of memory: each
operation reads and writes whole arrays, so a dozen operations are a dozen passes through
memory. Done a block of whole profiles at a time, with every temporary a block long, the
temporaries stay in the processor's cache, and the same operations run several times
faster (measured on 1.85 M points: about 2.7 x with blocks of 8 k points). Blocks hold whole
profiles, so that per-profile sums and per-profile medians never straddle two blocks.
"""

from __future__ import annotations

import numpy as np

#: The size of a block, in points of the block laid out as a rectangle (profiles x the
#: longest profile's points): small enough for a block's temporaries to stay in cache,
#: large enough that NumPy's cost per call is small beside the work.
BLOCK_POINTS = 8192


def profile_blocks(counts, target: int) -> list[tuple[int, int]]:
    """Consecutive profiles with ``counts`` points each, grouped: (first, end) per
    block, each block as many profiles as keep (profiles) x (its longest profile's
    points) within ``target`` (a longer profile is a block of its own). Every profile is
    in exactly one block, in order."""
    counts = np.asarray(counts, dtype=int)
    out: list[tuple[int, int]] = []
    p, n = 0, len(counts)
    while p < n:
        q, longest = p + 1, int(counts[p])
        while q < n and (q + 1 - p) * max(longest, int(counts[q])) <= target:
            longest = max(longest, int(counts[q]))
            q += 1
        out.append((p, q))
        p = q
    return out
