"""POST /smm over HTTP: the contract of DESIGN.md, answers checked by the closed-form planar FK."""

from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from tests.support.bundled import served_robots_message
from training.evaluate.references.planar3r import planar3r_position


def smm(client: TestClient, **overrides: Any) -> Any:
    body: dict[str, Any] = {
        "robot": "planar3r",
        "task": "position",
        "target": {"position": [0.5, 0.0]},
    }
    body.update(overrides)
    return client.post("/smm", json=body)


def all_configurations(answer: dict[str, Any]) -> np.ndarray:
    return np.array([q for c in answer["components"] for q in c["configurations"]]).reshape(-1, 3)


@pytest.mark.parametrize(
    ("position", "components"),
    [([0.5, 0.0], 2), ([0.0, -0.5], 2), ([2.0, 0.0], 1), ([-1.2, 1.2], 1)],
)
def test_component_count_follows_the_closed_form(
    client: TestClient, position: list[float], components: int
) -> None:
    response = smm(client, target={"position": position})
    assert response.status_code == 200
    answer = response.json()
    assert answer["status"] == "ok"
    assert len(answer["components"]) == components
    assert answer["redundancy"] == 1 and answer["joint_names"] == ["joint1", "joint2", "joint3"]
    assert answer["model"].startswith("planar3r-position@")


def test_every_returned_configuration_reaches_the_target_and_is_counted(client: TestClient) -> None:
    target = np.array([0.3, -0.6])
    answer = smm(client, target={"position": target.tolist()}, num_samples=1500).json()
    q = all_configurations(answer)
    error = np.linalg.norm(planar3r_position(q) - target, axis=1)
    assert error.max() <= 1e-6
    assert np.all(np.abs(q) <= np.pi)
    counts = answer["counts"]
    # At most num_samples drawn (the planar 3R draws in rounds and stops once a round
    # finds no new curve), every one of them accounted for.
    assert 0 < counts["sampled"] <= 1500
    rejected = counts["rejected_tolerance"] + counts["rejected_joint_limits"]
    assert counts["accepted"] + rejected == counts["sampled"]
    assert sum(c["size"] for c in answer["components"]) == counts["accepted"] == len(q)
    for component in answer["components"]:
        assert component["max_position_error"] <= 1e-6
        # Bounds cover every member and every point of the component's path.
        members = np.array(component["configurations"] + component["path"])
        np.testing.assert_allclose(members.min(0), component["joint_min"])
        np.testing.assert_allclose(members.max(0), component["joint_max"])
        assert component["representative"] in component["configurations"]
    assert set(answer["timings_ms"]) == {
        "encode",
        "sample",
        "correct",
        "accept",
        "connect",
        "summarise",
        "total",
    }


def test_out_of_reach_is_no_solution_not_an_error(client: TestClient) -> None:
    response = smm(client, target={"position": [3.5, 0.0]})
    assert response.status_code == 200
    answer = response.json()
    assert answer["status"] == "no_solution" and answer["components"] == []
    assert answer["counts"]["accepted"] == 0 and answer["counts"]["sampled"] == 1000


def test_absurdly_far_target_is_no_solution_not_a_crash(client: TestClient) -> None:
    # Every flow sample is non-finite here: correction must not hand an empty batch to
    # the kinematics.
    response = smm(client, target={"position": [1e308, 1e308]})
    assert response.status_code == 200
    assert response.json()["status"] == "no_solution"


def test_same_seed_same_answer_and_another_seed_another_sample(client: TestClient) -> None:
    first = smm(client, seed=7).json()
    second = smm(client, seed=7).json()
    other = smm(client, seed=8).json()
    for answer in (first, second, other):
        answer.pop("timings_ms")
    assert first == second
    assert first["components"] != other["components"]


def test_tolerance_is_honoured(client: TestClient) -> None:
    loose = smm(client, tolerance={"position": 1e-2}).json()
    tight = smm(client, tolerance={"position": 1e-12}).json()

    # The share accepted (the rounds may draw more for the tight tolerance).
    def rate(answer: dict) -> float:
        return answer["counts"]["accepted"] / answer["counts"]["sampled"]

    assert rate(loose) >= rate(tight) and tight["counts"]["rejected_tolerance"] > 0
    for component in tight["components"]:
        assert component["max_position_error"] <= 1e-12


def test_reference_orders_components_and_reports_the_nearest_member(client: TestClient) -> None:
    unordered = smm(client).json()
    far = unordered["components"][-1]["representative"]
    answer = smm(client, reference_configuration=far).json()
    first = answer["components"][0]
    assert first["distance_to_reference"] == pytest.approx(0.0, abs=1e-12)
    assert first["nearest_to_reference"] == far
    distances = [c["distance_to_reference"] for c in answer["components"]]
    assert distances == sorted(distances)


def test_max_configurations_caps_the_list_but_not_the_size(client: TestClient) -> None:
    answer = smm(client, max_configurations_per_component=5).json()
    for component in answer["components"]:
        assert len(component["configurations"]) == min(5, component["size"])
    assert sum(c["size"] for c in answer["components"]) == answer["counts"]["accepted"]


def detail_locations(response: Any) -> list[list[Any]]:
    return [error["loc"] for error in response.json()["detail"]]


@pytest.mark.parametrize(
    ("overrides", "location", "message"),
    [
        (
            {"target": {"position": [0.5, 0.0, 0.1]}},
            ["body", "target", "position"],
            "must have 2 values",
        ),
        ({"target": {"position": [0.5]}}, ["body", "target", "position"], "must have 2 values"),
        ({"target": {}}, ["body", "target", "position"], "Field required"),
        ({"target": {"position": [0.5, "a"]}}, ["body", "target", "position", 1], "valid number"),
        ({"target": {"position": [0.5, True]}}, ["body", "target", "position", 1], "valid number"),
        ({"target": {"position": ["0.5", 0]}}, ["body", "target", "position", 0], "valid number"),
        ({"num_samples": 0}, ["body", "num_samples"], "greater than or equal to 1"),
        ({"num_samples": "10"}, ["body", "num_samples"], "valid integer"),
        ({"tolerance": {"position": -1}}, ["body", "tolerance", "position"], "greater than 0"),
        (
            {"tolerance": {"orientation": 1e-3}},
            ["body", "tolerance", "orientation"],
            "pose and axis tasks",
        ),
        ({"reference_configuration": [0, 0]}, ["body", "reference_configuration"], "3 values"),
        ({"num_sample": 10}, ["body", "num_sample"], "Extra inputs are not permitted"),
        (
            {"target": {"position": [0.5, 0.0], "orientation": {"w": 1, "x": 0, "y": 0, "z": 0}}},
            ["body", "target", "orientation"],
            "not allowed for the position task",
        ),
    ],
)
def test_malformed_bodies_get_422_naming_the_field(
    client: TestClient, overrides: dict[str, Any], location: list[Any], message: str
) -> None:
    response = smm(client, **overrides)
    assert response.status_code == 422
    assert location in detail_locations(response)
    assert any(message in error["msg"] for error in response.json()["detail"])


def test_missing_top_level_field_and_nan_get_422(client: TestClient) -> None:
    response = client.post("/smm", json={"robot": "planar3r", "task": "position"})
    assert response.status_code == 422 and ["body", "target"] in detail_locations(response)
    raw = '{"robot": "planar3r", "task": "position", "target": {"position": [NaN, 0.0]}}'
    response = client.post("/smm", content=raw, headers={"content-type": "application/json"})
    assert response.status_code == 422
    assert ["body", "target", "position", 0] in detail_locations(response)
    assert "finite number" in response.json()["detail"][0]["msg"]


def test_unknown_robot_or_task_is_404_listing_what_is_served(client: TestClient) -> None:
    response = smm(client, robot="ur10")
    assert response.status_code == 404
    assert response.json()["detail"] == f"unknown robot 'ur10'; {served_robots_message()}"
    response = smm(client, task="pose")
    assert response.status_code == 404
    assert response.json()["detail"] == (
        "unknown task 'pose' for robot 'planar3r'; served tasks: position"
    )


def test_num_samples_over_the_limit_is_413(client: TestClient) -> None:
    response = smm(client, num_samples=5001)
    assert response.status_code == 413
    assert response.json()["detail"] == "num_samples must be at most 5000 on this server, got 5001"


def test_paths_come_ordered_and_include_paths_false_leaves_them_out(client: TestClient) -> None:
    """Redundancy 1: each component's path is exact by the closed form, inside the limits,
    0.05 rad apart, its arc length the sum of its steps; include_paths false drops the
    path only, and the components are the same."""
    target = np.array([0.5, 0.0])
    full = smm(client, target={"position": target.tolist()}).json()
    lean = smm(client, target={"position": target.tolist()}, include_paths=False).json()
    assert full["structure"] == lean["structure"] and not full["structure"]["near_singular"]
    assert full["structure"]["traced"] is True
    for with_path, without in zip(full["components"], lean["components"], strict=True):
        path = np.array(with_path["path"])
        assert np.abs(planar3r_position(path) - target).max() <= 1e-6
        steps = np.linalg.norm(np.angle(np.exp(1j * np.diff(path, axis=0))), axis=1)
        closing = np.linalg.norm(np.angle(np.exp(1j * (path[0] - path[-1]))))
        assert with_path["closed"] is True and max(steps.max(), closing) <= 0.05
        assert with_path["arc_length_rad"] == pytest.approx(steps.sum() + closing)
        assert without["path"] is None
        assert {k: v for k, v in without.items() if k != "path"} == {
            k: v for k, v in with_path.items() if k != "path"
        }
