"""report: a small planar report finds the closed-form component counts, returns exact
configurations within the limits, covers the closed-form SMM and writes both tables.
"""

from __future__ import annotations

from service.models.registry import ServedModel
from training.evaluate.rendering import markdown
from training.evaluate.report import build_report


def test_small_planar_report_meets_the_closed_form(planar3r: ServedModel) -> None:
    report = build_report(planar3r, num_targets=3, seed=1, num_samples=400)
    methods = report["methods"]
    assert isinstance(methods, dict)
    served = methods["FM + DLS"]
    assert served["returned"]["mm"] < 1e-3  # every returned configuration within 1e-6 m
    assert served["limit_violations"] == 0
    assert served["component_count"]["right"] == 1.0
    assert served["coverage_rad"]["p95"] < 0.1
    assert methods["FM"]["raw"]["mm"] > 1.0  # the raw flow is millimetres off
    assert methods["ODE"]["raw"]["mm"] < 1e-6  # RK5 drift only
    text = markdown("planar3r-position", report)
    assert "| FM + DLS |" in text and "| random-restart DLS |" in text and "count right" in text
