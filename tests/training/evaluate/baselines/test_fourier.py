"""training.evaluate.baselines.fourier: realtime-smm's Fourier baseline on the planar 3R.

Without realtime-smm: the baseline runs for the planar 3R only, says why elsewhere, and a
missing library or model is a reason to skip, not an error; the report's renderer knows
its rows. With realtime-smm (skipped otherwise, saying so): its robot has our closed-form
FK, and a tiny model trained with its own code (a 0.1 m grid, 1000 epochs of a 3 x 64
MLP; ~10 s) predicts the right number of branches, every point within 0.1 m of the
target and within 0.25 rad of the closed-form SMM (measured: means 10-56 mm, p95 0.01-0.14
rad); after the service's DLS correction every point is exact, still on the closed form,
and both rows carry every field the report renders.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from service.manifest import REPO_MODELS_DIR, Manifest
from service.models.registry import ServedModel
from service.pipeline.joint_space import joint_distance
from training.evaluate.baselines.fourier import (
    FOURIER,
    FOURIER_DLS,
    Budget,
    FourierModel,
    FourierUnavailable,
    fourier_targets,
    load,
    load_for,
    planar3r_robot,
    predict,
    supports,
    train,
)
from training.evaluate.metrics import summarise
from training.evaluate.references.planar3r import (
    closed_form_smm,
    expected_component_count,
    planar3r_position,
)
from training.evaluate.rendering import PAPER_TABLE_2, RAW_ROWS, markdown, table_2
from training.evaluate.truth import ground_truth

TORUS = np.ones(3, dtype=bool)


def _manifest(model_id: str) -> Manifest:
    return Manifest.model_validate_json((REPO_MODELS_DIR / model_id / "manifest.json").read_bytes())


def _on_torus(q: np.ndarray) -> np.ndarray:
    """(K, 6) cos and sin of every joint: Euclidean nearest there is nearest on the torus."""
    return np.concatenate([np.cos(q), np.sin(q)], axis=1)


def _distance_to(q: np.ndarray, exact: np.ndarray) -> np.ndarray:
    """(K,) joint-metric distance from each row of q to its nearest exact configuration."""
    nearest = cKDTree(_on_torus(exact)).query(_on_torus(q))[1]
    return joint_distance(q, exact[nearest], TORUS)


def test_it_runs_for_the_planar_3r_only_and_says_why_elsewhere() -> None:
    assert supports(_manifest("planar3r-position")) is None
    assert "planar 3R only" in (supports(_manifest("iiwa14-pose")) or "")
    assert "1-D SMMs only" in (supports(_manifest("iiwa14-position")) or "")
    with pytest.raises(FourierUnavailable, match="planar 3R only"):
        load_for(_manifest("iiwa14-pose"))


def test_a_missing_library_or_model_is_a_reason_to_skip(tmp_path: Path) -> None:
    with pytest.raises(FourierUnavailable, match=r"not installed|no trained model"):
        load(tmp_path)


def test_the_renderer_knows_its_rows() -> None:
    assert FOURIER in RAW_ROWS and FOURIER_DLS not in RAW_ROWS
    assert {FOURIER, FOURIER_DLS} <= PAPER_TABLE_2["planar3r-position"].keys()


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> FourierModel:
    pytest.importorskip("realtime_smm", reason="realtime-smm not installed (see fourier.py)")
    budget = Budget(pos_resolution_m=0.1, epochs=1000, hidden_dims=(64, 64, 64))
    return train(tmp_path_factory.mktemp("fourier"), budget)


def test_its_robot_is_our_planar_3r() -> None:
    pytest.importorskip("realtime_smm", reason="realtime-smm not installed (see fourier.py)")
    robot = planar3r_robot()
    for q in np.random.default_rng(0).uniform(-np.pi, np.pi, (20, 3)):
        np.testing.assert_allclose(
            robot.forward_kinematics(q)[:2, 3], planar3r_position(q), atol=1e-12
        )


@pytest.mark.parametrize("rho", [0.5, 2.0])
def test_predicted_points_lie_near_the_closed_form_smm(tiny: FourierModel, rho: float) -> None:
    target = rho * np.array([np.cos(2.0), np.sin(2.0)])
    smm = predict(tiny, target, 400)
    assert int(smm.branch.max()) + 1 == expected_component_count(rho)
    assert len(smm.q_rad) == 400 and smm.wall_time_ms > 0
    assert np.linalg.norm(planar3r_position(smm.q_rad) - target, axis=1).mean() < 0.1
    exact = np.concatenate(closed_form_smm(target, phi_step_rad=1e-3))
    assert np.percentile(_distance_to(smm.q_rad, exact), 95) < 0.25


def test_both_rows_are_complete_and_the_corrected_one_exact(
    tiny: FourierModel, planar3r: ServedModel
) -> None:
    q_target = np.array([0.3, 2.0, 1.5])
    assert expected_component_count(float(np.linalg.norm(planar3r_position(q_target)))) == 2
    raw, corrected = fourier_targets(planar3r, tiny, q_target, 400)
    assert raw.sampled == corrected.sampled == len(raw.returned) == 400
    assert raw.component_count == corrected.component_count == 2
    assert raw.time_ms < corrected.time_ms == corrected.stage_ms["total"]  # type: ignore[index]
    tolerance = planar3r.manifest.defaults.tolerance_position_m
    assert len(corrected.returned) > 0.9 * 400
    assert corrected.returned_position_m.max() <= tolerance
    exact = np.concatenate(closed_form_smm(planar3r_position(q_target), phi_step_rad=1e-4))
    assert _distance_to(corrected.returned, exact).max() < 1e-3

    truth = ground_truth(planar3r, q_target, seed=0)
    rows = {FOURIER: summarise(planar3r, [raw], [truth])}
    rows[FOURIER_DLS] = summarise(planar3r, [corrected], [truth])
    for summary in rows.values():
        assert {"raw", "returned", "keep_rate", "median_time_ms", "coverage_rad"} <= summary.keys()
        assert summary["component_count"]["right"] == 1.0  # type: ignore[index]
    report = {
        "model": "planar3r-position@test", "targets": 1, "seed": 0, "num_samples": 400,
        "methods": rows, "near_boundary": {"targets": 0, "indices": []},
        "fourier_training": tiny.training,
    }  # fmt: skip
    text = markdown("planar3r-position", report)
    assert f"| {FOURIER} |" in text and f"| {FOURIER_DLS} |" in text
    assert "Clark and Xie's package 0.1.2" in text
    assert f"| planar3r-position | {FOURIER_DLS} |" in table_2({"planar3r-position": report})
