"""Choosing a model's serving defaults by measurement: a built-in sweep with the
evaluation's own measures, for any robot trained from a URDF. Its design (targets,
reference, measures, candidates and the rule) is docs/sweep.md.

One direction of imports: plan <- measures <- rule <- reasons <- search <- command.
"""

from training.sweep.measures import (
    Candidate,
    Measures,
    TimePowerRow,
    agreement,
    coverage_distances,
    nearest_reference,
    reference_answer,
)
from training.sweep.plan import AXES, Axis, Setting, SweepPlan
from training.sweep.rule import (
    COUNT_RIGHT_MARGIN,
    COVERAGE_MARGIN,
    KEEP_RATE_MARGIN,
    SAMPLER_KEEP_RATE_MARGIN,
    TIME_POWER_GAIN,
    pick,
    pick_time_power,
)
from training.sweep.search import SweepResult, judged_sweep, sweep_defaults

__all__ = [
    "AXES",
    "COUNT_RIGHT_MARGIN",
    "COVERAGE_MARGIN",
    "KEEP_RATE_MARGIN",
    "SAMPLER_KEEP_RATE_MARGIN",
    "TIME_POWER_GAIN",
    "Axis",
    "Candidate",
    "Measures",
    "Setting",
    "SweepPlan",
    "SweepResult",
    "TimePowerRow",
    "agreement",
    "coverage_distances",
    "judged_sweep",
    "nearest_reference",
    "pick",
    "pick_time_power",
    "reference_answer",
    "sweep_defaults",
]
