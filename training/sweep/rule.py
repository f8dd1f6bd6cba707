"""The sweep's choice rule: its margins, `pick` over the candidates of one axis and
`pick_time_power` for the sampler's time grid (docs/sweep.md, The rule)."""

from __future__ import annotations

from collections.abc import Sequence

from training.sweep.measures import Candidate, TimePowerRow
from training.sweep.plan import Axis

# The rule's margins, as fractions. One point of keep rate is the spread the bundled
# models' sweeps saw between 20 and 50 Euler steps; one target in 20 of count right; two
# points of recall is one reference component in 50.
KEEP_RATE_MARGIN = 0.01
# The sampler axes' keep-rate margin (docs/sweep.md says why it is wider).
SAMPLER_KEEP_RATE_MARGIN = 0.15
SAMPLER_AXES: frozenset[str] = frozenset({"sampler_steps", "reflow_steps"})
# Coverage p95 may exceed the best candidate's by this fraction of it: the 20-target
# p95 moves by ~1-3 % between settings that find the same components (the bundled sweeps).
COVERAGE_MARGIN = 0.10
COUNT_RIGHT_MARGIN = 0.05
RECALL_MARGIN = 0.02
# Merged reference components per target a candidate may have beyond the fewest on its axis.
MERGES_MARGIN = 0.0
# A power of the sampler's time grid other than 1 must lower the mean raw error by this
# fraction of the uniform grid's (the Panda models measured within 2 % across powers).
TIME_POWER_GAIN = 0.05


def pick(rows: Sequence[Candidate]) -> Candidate:
    """The rule of docs/sweep.md over the candidates of one axis."""
    if not rows or len({row.axis for row in rows}) != 1:
        raise ValueError(f"pick takes the candidates of one axis, got {[r.axis for r in rows]}")
    most_answered = max(row.measures.answered for row in rows)
    answering = [row for row in rows if row.measures.answered == most_answered]
    best_keep = max(row.measures.keep_rate for row in rows)
    best_count = max(row.measures.count_right for row in rows)
    best_recall = max((_recall(row) for row in rows), default=0.0)
    best_coverage = min(_coverage(row) for row in rows)
    fewest_merges = min(row.measures.merges_per_target for row in rows)
    keep_margin = keep_rate_margin(rows[0].axis)
    within = [
        row
        for row in answering
        if row.measures.keep_rate >= best_keep - keep_margin
        and row.measures.count_right >= best_count - COUNT_RIGHT_MARGIN
        and _recall(row) >= best_recall - RECALL_MARGIN
        and _coverage(row) <= best_coverage * (1.0 + COVERAGE_MARGIN)
        and row.measures.merges_per_target <= fewest_merges + MERGES_MARGIN
    ]
    if within:
        return min(within, key=lambda row: row.cost)
    return max(
        answering,
        key=lambda row: (
            row.measures.count_right,
            -row.measures.merges_per_target,
            row.measures.keep_rate,
            _recall(row),
            -row.cost,
        ),
    )


def pick_time_power(rows: Sequence[TimePowerRow]) -> TimePowerRow:
    """The first row (the uniform grid) unless another lowers its raw error by at least
    TIME_POWER_GAIN; then the one with the lowest."""
    if not rows:
        raise ValueError("pick_time_power takes at least one row")
    lowest = min(rows, key=lambda row: row.raw_error_pct_reach)
    if lowest.raw_error_pct_reach <= (1.0 - TIME_POWER_GAIN) * rows[0].raw_error_pct_reach:
        return lowest
    return rows[0]


def keep_rate_margin(axis: Axis) -> float:
    """How far below the best keep rate a candidate of `axis` may be (module docstring)."""
    return SAMPLER_KEEP_RATE_MARGIN if axis in SAMPLER_AXES else KEEP_RATE_MARGIN


def _coverage(row: Candidate) -> float:
    """Coverage p95 for the rule: no reference configuration to cover puts none behind."""
    coverage = row.measures.coverage_p95_rad
    return 0.0 if coverage is None else coverage


def _recall(row: Candidate) -> float:
    """Recall for the rule: a target set with nothing to recall puts no candidate behind."""
    return 1.0 if row.measures.recall is None else row.measures.recall
