"""Two figures side by side in words, as the judge, the benchmark and the docs write them.

`figure_pair` gives "ours vs theirs" at three significant digits, or at as many more (up
to six) as tell the two apart: two figures said to differ never print the same.
"""

from __future__ import annotations

MIN_DIGITS, MAX_DIGITS = 3, 6


def figure_pair(ours: float, theirs: float) -> str:
    """`ours vs theirs`, each to the fewest significant digits from MIN_DIGITS to
    MAX_DIGITS at which they print differently (MAX_DIGITS when they never do)."""
    for digits in range(MIN_DIGITS, MAX_DIGITS + 1):
        left, right = f"{ours:.{digits}g}", f"{theirs:.{digits}g}"
        if left != right:
            break
    return f"{left} vs {right}"
