"""examples/planner.py against a real server, its choice checked independently.

The example runs as a user runs it (`python examples/planner.py --url ...`, the client's
dependencies only) and writes its request and choice with `--json`. The test then sends
the same request itself (raw httpx) and checks, with numpy and the limits of GET /robots:
the chosen component is the one nearest to q. With the scene and the clearance objective
(the default): the choice is the component's safest configuration, and it and every
point of the component's path are clear of the table, the shelf and the arm itself by
the margin by coal on the URDF's own meshes (training/evaluate/references/collision.py).
With `--objective limit-margin`: the chosen configuration has the largest
joint-limit margin over that component's configurations and path points (the smallest
margin first, ties to 1e-6 rad broken by the next: on this pose q4 is constant on the
component), and the margins and limiting joint are what the example says. Either way it reaches
the target by the independent DH forward kinematics of
training/evaluate/references/iiwa14.py
(1e-6 m, 1e-6 rad) and lies inside the limits; the walk starts at the path point
nearest to the component's member nearest to q, ends at the chosen configuration, and its
length is the sum of its steps, no shorter than the straight line between its ends and no
longer than the component's arc length. The motion the example then asks for (POST
/smm/self-motion) starts at that nearest point and ends at the choice, its points at most
0.05 rad apart, exact by the DH table and clear of the scene by coal.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from service.pipeline.collision.scene import Obstacle
from tools.local_server import LocalServer
from training.evaluate.references.iiwa14 import dh_pose as iiwa14_pose
from training.evaluate.references.rotations import rotation_angle_rad
from training.evaluate.scenes.coal_model import CoalModel

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def server() -> Iterator[LocalServer]:
    with LocalServer() as running:
        yield running


def rotation(w: float, x: float, y: float, z: float) -> np.ndarray:
    """(3, 3) rotation matrix of a unit quaternion."""
    n = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def run_planner(server: LocalServer, tmp_path: Path, *options: str) -> dict[str, Any]:
    """The example as a user runs it; its --json record."""
    record_path = tmp_path / "choice.json"
    command = [sys.executable, "examples/planner.py", "--url", server.url]
    run = subprocess.run(
        [*command, "--json", str(record_path), *options],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    print(run.stdout)
    for line in ("q now:", "service:", "scene:", "choice:", "walk:", "why:", "motion:"):
        assert line in run.stdout
    record: dict[str, Any] = json.loads(record_path.read_text())
    return record


def test_the_planner_picks_the_nearest_component_and_its_safest_configuration(
    server: LocalServer, tmp_path: Path
) -> None:
    record = run_planner(server, tmp_path)
    request: dict[str, Any] = record["request"]
    choice: dict[str, Any] = record["choice"]
    answer = httpx.post(f"{server.url}/smm", json=request, timeout=60).json()
    assert answer["collision"]["obstacles"] == 3 and answer["collision"]["self_checked"]
    distances = [c["distance_to_reference"] for c in answer["components"]]
    nearest = answer["components"][int(np.argmin(distances))]
    assert choice["component_id"] == nearest["id"] and choice["objective"] == "clearance"
    assert choice["configuration"] == nearest["safest_configuration"]
    assert choice["clearance_m"] == nearest["clearance_m"]

    # Clear of the scene and of the arm itself by the margin, on the URDF's own meshes.
    obstacles = [
        Obstacle.of(i, o["shape"], o["dimensions"], o["position"], None)
        for i, o in enumerate(request["obstacles"])
    ]
    margin_m = request["collision"]["margin_m"]
    coal = CoalModel.of_directory(ROOT / "models" / "iiwa14-pose")
    chosen = np.array(choice["configuration"])
    path = np.array(nearest["path"])
    exact = coal.clearance_m(np.vstack([chosen, path]), obstacles)
    assert exact.min() >= margin_m
    # The spheres' clearance is a lower bound of coal's.
    assert nearest["safest_clearance_m"] <= exact[0] + 1e-9
    assert nearest["clearance_m"] <= exact.min() + 1e-9
    pose = iiwa14_pose(chosen[None])[0]
    assert np.linalg.norm(pose[:3, 3] - np.array(request["target"]["position"])) < 1e-6

    # The motion: from the point nearest q to the choice, exact, 0.05 rad apart, clear.
    motion = record["motion"]
    assert motion["status"] == "ok"
    steps = np.array(motion["path"])
    assert np.abs(steps[0] - np.array(record["motion_request"]["start"])).max() <= 1e-6
    assert np.abs(steps[-1] - chosen).max() <= 1e-6
    assert np.linalg.norm(np.diff(steps, axis=0), axis=1).max() <= 0.05
    reached = iiwa14_pose(steps)
    assert np.linalg.norm(reached[:, :3, 3] - pose[:3, 3], axis=1).max() <= 1e-6
    goal_rotation = np.broadcast_to(pose[:3, :3], (len(steps), 3, 3))
    assert rotation_angle_rad(reached[:, :3, :3], goal_rotation).max() <= 1e-6
    assert coal.clearance_m(steps, obstacles).min() >= margin_m


def test_the_planner_picks_the_nearest_component_and_its_largest_margin(
    server: LocalServer, tmp_path: Path
) -> None:
    record = run_planner(server, tmp_path, "--objective", "limit-margin")
    request: dict[str, Any] = record["request"]
    choice: dict[str, Any] = record["choice"]

    answer = httpx.post(f"{server.url}/smm", json=request, timeout=60).json()
    robots = httpx.get(f"{server.url}/robots").json()["models"]
    iiwa = next(m for m in robots if (m["robot"], m["task"]) == ("iiwa14", "pose"))
    lower, upper = np.array(iiwa["joint_lower"]), np.array(iiwa["joint_upper"])
    assert not any(iiwa["periodic_joints"])  # so the plain Euclidean metric is the service's

    # The nearest component to q.
    q = np.array(request["reference_configuration"])
    distances = [c["distance_to_reference"] for c in answer["components"]]
    nearest = answer["components"][int(np.argmin(distances))]
    assert choice["component_id"] == nearest["id"]
    assert choice["components"] == len(answer["components"])
    reported = np.linalg.norm(np.array(nearest["nearest_to_reference"]) - q)
    assert reported == pytest.approx(nearest["distance_to_reference"], abs=1e-9)

    # The largest joint-limit margin over its configurations and path points: the smallest
    # margin first, ties (to 1e-6 rad) broken by the next smallest, and so on.
    candidates = np.array(nearest["configurations"] + (nearest["path"] or []))
    margins = np.minimum(candidates - lower, upper - candidates)  # (K, 7)
    ranked = np.round(np.sort(margins, axis=1), 6)  # (K, 7), smallest first
    best = int(np.lexsort(ranked.T[::-1])[-1])  # lexicographic maximum
    chosen = np.array(choice["configuration"])
    chosen_margins = np.minimum(chosen - lower, upper - chosen)
    np.testing.assert_array_equal(np.round(np.sort(chosen_margins), 6), ranked[best])
    assert any(np.array_equal(chosen, c) for c in candidates)  # a member, as returned
    assert choice["margin_rad"] == pytest.approx(chosen_margins.min(), abs=1e-12)
    assert choice["limiting_joint"] == iiwa["joint_names"][int(np.argmin(chosen_margins))]
    assert list(choice["margins_rad"].values()) == pytest.approx(np.sort(chosen_margins))
    nearest_ranked = np.round(np.sort(list(choice["nearest_margins_rad"].values())), 6)
    assert nearest_ranked.tolist() <= ranked[best].tolist()

    # It reaches the target, by an FK that shares no code with the service, inside the limits.
    target = request["target"]
    pose = iiwa14_pose(chosen[None])[0]
    assert np.linalg.norm(pose[:3, 3] - np.array(target["position"])) < 1e-6
    goal = rotation(*(target["orientation"][k] for k in "wxyz"))
    assert rotation_angle_rad(pose[None, :3, :3], goal[None])[0] < 1e-6
    assert np.all((chosen >= lower) & (chosen <= upper))

    # The walk along the path: from the point nearest to q's nearest member, to the choice.
    path = np.array(nearest["path"])
    start, end = choice["path_from_index"], choice["path_to_index"]
    gaps = np.linalg.norm(path - np.array(nearest["nearest_to_reference"]), axis=1)
    assert start == int(np.argmin(gaps))
    assert end == int(np.argmin(np.linalg.norm(path - chosen, axis=1)))
    assert not nearest["closed"]  # this pose's components are open: one way to walk
    lo, hi = sorted((start, end))
    steps = np.linalg.norm(np.diff(path[lo : hi + 1], axis=0), axis=1)
    assert choice["path_steps"] == hi - lo
    assert choice["path_length_rad"] == pytest.approx(steps.sum(), rel=1e-9)
    straight = np.linalg.norm(path[end] - path[start])
    assert straight - 1e-9 <= choice["path_length_rad"] <= 1.001 * nearest["arc_length_rad"]
