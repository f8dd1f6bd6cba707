"""Truth figures side by side in words, as the judge, the benchmark and the docs write them.

`figure_pair` gives "ours vs theirs" at three significant digits, or at as many more (up
to six) as tell the two apart: two figures said to differ never print the same.
`worse_than` and `better_than` read two sets of truth figures (`TRUTH_FIGURES`) the one
way all three do: a figure either set lacks is skipped, equal figures are neither.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping

# The truth figures, their names, and whether more is better.
TRUTH_FIGURES = (
    ("count_right", "count right", True),
    ("splits_per_target", "splits", False),
    ("merges_per_target", "merges", False),
    ("recall", "recall", True),
    ("coverage_p95_rad", "coverage p95 rad", False),
)

MIN_DIGITS, MAX_DIGITS = 3, 6


def figure_pair(ours: float, theirs: float) -> str:
    """`ours vs theirs`, each to the fewest significant digits from MIN_DIGITS to
    MAX_DIGITS at which they print differently (MAX_DIGITS when they never do)."""
    for digits in range(MIN_DIGITS, MAX_DIGITS + 1):
        left, right = f"{ours:.{digits}g}", f"{theirs:.{digits}g}"
        if left != right:
            break
    return f"{left} vs {right}"


Figures = Mapping[str, float | None]


def _sides(
    candidate: Figures, incumbent: Figures, coverage_margin: float
) -> Iterator[tuple[str, bool, bool]]:
    """Each figure both sets have, written "name candidate vs incumbent", with whether the
    candidate is worse (coverage p95 only beyond (1 + coverage_margin) times the
    incumbent's) and whether it is better."""
    for key, name, more_is_better in TRUTH_FIGURES:
        ours, theirs = candidate.get(key), incumbent.get(key)
        if ours is None or theirs is None:
            continue
        gain = ours - theirs if more_is_better else theirs - ours
        worse = ours > theirs * (1.0 + coverage_margin) if key == "coverage_p95_rad" else gain < 0
        yield f"{name} {figure_pair(ours, theirs)}", worse, gain > 0


def worse_than(candidate: Figures, incumbent: Figures, coverage_margin: float = 0.0) -> list[str]:
    """The figures on which `candidate` is worse than `incumbent`, each as "name candidate
    vs incumbent"; coverage p95 only beyond (1 + coverage_margin) times the incumbent's."""
    return [pair for pair, worse, _ in _sides(candidate, incumbent, coverage_margin) if worse]


def better_than(candidate: Figures, incumbent: Figures) -> list[str]:
    """The figures on which `candidate` is better than `incumbent`, as `worse_than` writes
    them."""
    return [pair for pair, _, better in _sides(candidate, incumbent, 0.0) if better]
