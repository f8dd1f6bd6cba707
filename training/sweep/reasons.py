"""The human-readable reasons the sweep writes into a manifest's `defaults.reasons`, with
every candidate's measured figures. Manifests and the docs quote them: their wording is
part of the models' record."""

from __future__ import annotations

from collections.abc import Sequence

from training.defaults import CONNECTIVITY_REASON
from training.sweep.measures import Candidate, TimePowerRow
from training.sweep.plan import (
    JOINT_DLS_AXES,
    UNIT,
    Axis,
    Setting,
    SweepPlan,
    connectivity_step_field,
)
from training.sweep.rule import (
    COUNT_RIGHT_MARGIN,
    COVERAGE_MARGIN,
    RECALL_MARGIN,
    TIME_POWER_GAIN,
    keep_rate_margin,
)

# The Defaults reason each axis writes.
REASON_KEY: dict[Axis, str] = {
    "flow_precision_bits": "sampler_precision",
    "sampler_steps": "sampler",
    "reflow_steps": "sampler_flow",
    "correction_steps": "correction_steps",
    "num_samples": "num_samples",
    "connectivity_step_rad": "connectivity",
}


# -- the reasons -------------------------------------------------------------------------------


def figures(row: Candidate) -> str:
    m = row.measures
    recall = "-" if m.recall is None else f"{m.recall:.1%}"
    coverage = "-" if m.coverage_p95_rad is None else f"{m.coverage_p95_rad:.3f} rad"
    return (
        f"{row.label}: keep rate {m.keep_rate:.1%}, answered {m.answered}/{m.targets}, "
        f"count right {m.count_right:.0%}, merges per target {m.merges_per_target:.2f}, "
        f"recall {recall}, coverage p95 {coverage}, "
        f"median {m.median_total_ms:.0f} ms per query in this process"
    ).replace("%", " %")


def raw_figures(row: TimePowerRow) -> str:
    return (
        f"mean raw error {row.raw_error_pct_reach:.3g} % of the reach "
        f"(position {row.raw_position_error_mm:.3g} mm)"
    )


def time_power_reason(
    rows: Sequence[TimePowerRow], best: TimePowerRow, setting: Setting, seed: int
) -> str:
    """Why the grid's power was chosen, with every candidate's raw error."""
    return (
        f"time power {best.time_power:g} by the rule of training/sweep/rule.py (the uniform grid "
        f"unless another power lowers the flow's mean raw error by at least "
        f"{TIME_POWER_GAIN * 100:g} %); {setting.num_samples} samples on each of the "
        f"sweep's held-out targets (seed {seed}) at {setting.sampler_steps} Euler steps, "
        "before correction: " + "; ".join(f"{row.time_power:g}: {raw_figures(row)}" for row in rows)
    )


def _points(fraction: float) -> str:
    points = fraction * 100
    return f"{points:g} point" + ("" if points == 1 else "s")


def axis_reason(
    rows: Sequence[Candidate], best: Candidate, seed: int, plan: SweepPlan, redundancy: int
) -> str:
    """Why `best` was chosen, with the measured figures of every candidate on its axis."""
    axis = best.axis
    m = best.measures
    reference = plan.reference_setting(redundancy)
    joint = f" at {best.setting.correction_steps} DLS steps" if axis in JOINT_DLS_AXES else ""
    return (
        f"{best.value} {UNIT[axis]}{joint} by the rule of training/sweep/rule.py (the cheapest "
        f"candidate answering the most targets within {_points(keep_rate_margin(axis))} "
        f"of the best keep rate, {COUNT_RIGHT_MARGIN * 100:g} points of the best "
        f"count right, {RECALL_MARGIN * 100:g} points of the best recall and "
        f"{COVERAGE_MARGIN * 100:g} % of the best coverage p95, merging no more than the "
        f"fewest); "
        f"{m.targets} held-out targets (FK of random configurations, seed {seed}), with "
        f"{best.setting.describe(leaving_out=axis)}, against a dense reference of the same "
        f"pipeline ({reference.describe()}): " + "; ".join(figures(row) for row in rows)
    )


def chosen_reasons(
    rows: Sequence[Candidate],
    best: Candidate,
    chosen: Setting,
    axes: Sequence[Axis],
    seed: int,
    plan: SweepPlan,
    redundancy: int,
    power_reason: str,
) -> dict[str, str]:
    """The Defaults reasons that choosing `best` on its axis writes (`chosen`: the setting
    before it; `power_reason`: why the time grid, with the sampler's steps)."""
    axis = best.axis
    reasons = {REASON_KEY[axis]: axis_reason(rows, best, seed, plan, redundancy)}
    joint_dls = best.setting.correction_steps
    if "correction_steps" not in axes and joint_dls != chosen.correction_steps:
        reasons["correction_steps"] = (
            f"{joint_dls} DLS steps, chosen jointly with the sampler (reasons.{REASON_KEY[axis]})"
        )
    if axis == "sampler_steps":
        reasons["sampler"] = f"{reasons['sampler']}. Time grid: {power_reason}"
    if axis == "connectivity_step_rad":
        reasons["connectivity"] = (
            f"{connectivity_step_field(redundancy)} = {reasons['connectivity']}; the "
            "other parameters from the per-r table of training/defaults.py: "
            f"{CONNECTIVITY_REASON}"
        )
    return reasons
