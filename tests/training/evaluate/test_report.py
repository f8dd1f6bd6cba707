"""report: a small planar report finds the closed-form component counts, returns exact
configurations within the limits (by the service's FK and by the closed form's), covers
the closed-form SMM, checks the returned paths, times the connect stage (median and p95,
the restarts' too) and writes every table; the Fourier baseline runs or the report says
why not. `smm-train report --candidate` reports the served defaults so changed, written
only away from the committed reports.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from service.models.registry import ServedModel
from training.cli import main as smm_train
from training.evaluate.baselines.fourier import FOURIER
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
    assert 0.9 < served["keep_rate"] <= 1.0  # path points are not counted as kept
    spacing = planar3r.manifest.defaults.connectivity.path_spacing_rad
    assert served["path_points_mean"] > 0 and served["path_max_gap_rad"] <= 2 * spacing
    assert served["path_points_outside_limits"] == 0
    assert served["path_max_position_error_m"] <= planar3r.manifest.defaults.tolerance_position_m
    assert served["near_singular_targets"] == 0.0
    for name in ("FM + DLS", "random-restart DLS"):
        median, p95 = methods[name]["median_stage_ms"], methods[name]["p95_stage_ms"]
        assert 0 < median["connect"] <= p95["connect"]
    assert "cluster" not in served["median_stage_ms"]
    assert methods["FM"]["raw"]["mm"] > 1.0  # the raw flow is millimetres off
    assert methods["ODE"]["raw"]["mm"] < 1e-6  # RK5 drift only
    assert report["wrong_count_targets"] == []
    checked = report["reference_fk"]
    assert isinstance(checked, dict) and checked["configurations"] > 0
    assert checked["max_position_error_m"] <= 1e-6 and checked["within_tolerance"]
    # The Fourier baseline ran (realtime-smm and a trained model here) or says why not.
    skipped = report.get("skipped", {})
    assert isinstance(skipped, dict)
    if FOURIER not in methods:
        assert "realtime-smm" in skipped[FOURIER] or "no trained model" in skipped[FOURIER]
    text = markdown("planar3r-position", report)
    assert "| FM + DLS |" in text and "| random-restart DLS |" in text and "count right" in text
    assert "connect p95 ms" in text and "max gap rad" in text and "Count right: " in text


def test_a_candidate_is_reported_at_its_defaults_away_from_the_reports(
    planar3r: ServedModel, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    steps = planar3r.manifest.defaults.correction_steps + 1
    small = ["report", "--model", "planar3r-position", "--targets", "2", "--num-samples", "50"]
    smm_train([*small, "--candidate", f'{{"correction_steps": {steps}}}', "--out", str(tmp_path)])
    report = json.loads((tmp_path / "planar3r-position.json").read_text())
    assert report["defaults"]["correction_steps"] == steps
    assert report["defaults"]["sampler"] == planar3r.manifest.defaults.sampler.model_dump()
    capsys.readouterr()
    with pytest.raises(SystemExit):
        smm_train([*small, "--candidate", "{}"])
    assert "--candidate: give --out" in capsys.readouterr().err
