"""references.panda and the bundled Panda: the exact ground truth, checked independently.

The float64 URDF chain (references.urdf_chain, checked on its own in test_urdf_chain.py)
reads the bundled panda.urdf as the source ships it (panda_hand_tcp 0.1034 m beyond the
hand, the limits, the reference's DH table and limits to 1e-12, q7 not moving the TCP).
On 20 random targets, by that chain: every point of the exact pose SMM reaches the
target within 1e-9 m and 1e-9 rad inside the limits, consecutive points are at most
0.05 rad apart, the generating configuration lies on a component, and an independent
predictor-corrector continuation along the Jacobian's null space, started inside each
component, stays on that component alone and runs to the limits (or around the loop)
over the component's arc length: so the components are neither split nor merged. The
4-D position SMM's points are exact and in the limits, hold the generating
configuration, and a feasible walk along the fibre stays in one component.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from scipy.spatial import cKDTree

from service.manifest import REPO_MODELS_DIR
from training.evaluate.references import panda
from training.evaluate.references.iiwa14 import PositionSmm
from training.evaluate.references.rotations import rotation_angle_rad
from training.evaluate.references.urdf_chain import UrdfChain, read_chain

PANDA_URDF = REPO_MODELS_DIR / "robots" / "panda.urdf"
LOWER = np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
UPPER = np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])


@pytest.fixture(scope="module")
def chain() -> UrdfChain:
    return read_chain(PANDA_URDF, "panda_hand_tcp", "panda_link0")


def test_the_bundled_panda_urdf_is_the_source_chain(chain: UrdfChain) -> None:
    text = PANDA_URDF.read_text()
    assert "63792d2679f22c4e41cda2c4d9d903644e628970ad0656b9eec8485113941555" in text
    body = text.split("-->", 1)[1]  # kinematics and collision geometry, no visuals
    assert "<visual" not in body and "package://" not in body
    meshes = re.findall(r'<mesh filename="([^"]+)"', body)
    assert len(meshes) == 9 and all(m.startswith("panda/collision/") for m in meshes)
    assert all((PANDA_URDF.parent / m).is_file() for m in meshes)
    assert [j.name for j in chain.movable] == [f"panda_joint{i}" for i in range(1, 8)]
    np.testing.assert_array_equal(chain.lower, LOWER)
    np.testing.assert_array_equal(chain.upper, UPPER)
    np.testing.assert_array_equal(panda.LOWER_RAD, LOWER)  # the reference's limits
    np.testing.assert_array_equal(panda.UPPER_RAD, UPPER)
    q = np.random.default_rng(2).uniform(LOWER, UPPER, (500, 7))
    tcp = chain.pose(q)
    hand = read_chain(PANDA_URDF, "panda_hand", "panda_link0").pose(q)
    np.testing.assert_allclose(tcp[:, :3, 3], hand[:, :3, 3] + 0.1034 * hand[:, :3, 2], atol=1e-15)
    np.testing.assert_allclose(tcp, panda.dh_pose(q), rtol=0, atol=1e-12)  # the reference's table
    turned = q + np.array([0, 0, 0, 0, 0, 0, 1.3])  # q7 turns the TCP about its own point
    np.testing.assert_allclose(chain.pose(turned)[:, :3, 3], tcp[:, :3, 3], rtol=0, atol=1e-12)
    spec = json.loads((REPO_MODELS_DIR / "robots" / "panda.json").read_text())
    assert (spec["base_link"], spec["end_effector_link"]) == ("panda_link0", "panda_hand_tcp")
    assert (REPO_MODELS_DIR / spec["urdf"]).resolve() == PANDA_URDF.resolve()
    assert (REPO_MODELS_DIR / "robots" / "panda.LICENSE").read_text().lstrip().startswith("Apache")


def _targets(count: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(LOWER, UPPER, (count, 7))


@pytest.fixture(scope="module")
def pose_cases(chain: UrdfChain) -> list[tuple[np.ndarray, np.ndarray, list]]:
    """20 random targets: (generating q (7,), its pose (4, 4), the exact components)."""
    cases = []
    for q in _targets(20, seed=3):
        pose = chain.pose(q[None])[0]
        cases.append((q, pose, panda.pose_smm(pose[:3, 3], pose[:3, :3])))
    return cases


def test_pose_smm_points_are_exact_in_the_limits_dense_and_hold_the_target(
    chain: UrdfChain, pose_cases: list
) -> None:
    for q_target, pose, components in pose_cases:
        assert components
        points = np.concatenate([c.q_rad for c in components])
        reached = chain.pose(points)
        assert np.abs(reached[:, :3, 3] - pose[:3, 3]).max() < 1e-9
        assert rotation_angle_rad(reached[:, :3, :3], pose[None, :3, :3]).max() < 1e-9
        assert np.all((points >= LOWER) & (points <= UPPER))
        for component in components:
            ring = np.concatenate([component.q_rad, component.q_rad[:1]]) if component.closed \
                else component.q_rad  # fmt: skip
            steps = np.linalg.norm(np.diff(ring, axis=0), axis=1)
            assert steps.max(initial=0.0) <= 0.05 + 1e-9
            assert component.arc_length_rad == pytest.approx(steps.sum(), rel=1e-12, abs=1e-12)
        nearest = min(np.linalg.norm(c.q_rad - q_target, axis=1).min() for c in components)
        assert nearest < 0.05


def _continue(
    chain: UrdfChain,
    pose: np.ndarray,
    start: np.ndarray,
    direction: np.ndarray,
    step_rad: float = 0.04,
    max_steps: int = 800,
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Predictor-corrector along the pose fibre from `start` (B, 7), first along
    `direction` (B, 7): tangent from the SVD of the URDF chain's Jacobian, Newton back
    to the pose. Each trace stops where it leaves the limits (its length counted to the
    crossing) or back at its start (a loop). (B,) lengths and each trace's points."""
    q, tangent = start.copy(), direction.copy()
    length = np.zeros(len(q))
    running = np.ones(len(q), bool)
    paths: list[list[np.ndarray]] = [[p.copy()] for p in q]
    for _ in range(max_steps):
        if not running.any():
            break
        live = np.flatnonzero(running)
        null = np.linalg.svd(chain.jacobian(q[live]))[2][:, -1]  # (L, 7)
        null *= np.sign(np.sum(null * tangent[live], axis=1))[:, None]
        candidate = q[live] + step_rad * null
        for _ in range(3):
            reached = chain.pose(candidate)
            error_r = pose[None, :3, :3] @ np.swapaxes(reached[:, :3, :3], 1, 2)
            skew = (error_r - np.swapaxes(error_r, 1, 2)) / 2
            turn = np.stack([skew[:, 2, 1], skew[:, 0, 2], skew[:, 1, 0]], 1)  # (L, 3)
            error = np.concatenate([pose[None, :3, 3] - reached[:, :3, 3], turn], 1)
            candidate = candidate + np.einsum(
                "bij,bj->bi", np.linalg.pinv(chain.jacobian(candidate)), error
            )
        moved = np.linalg.norm(candidate - q[live], axis=1)
        inside = np.all((candidate >= LOWER) & (candidate <= UPPER), axis=1)
        # The fraction of the step inside the limits, on the joint that leaves them first.
        over = np.maximum(candidate - UPPER, LOWER - candidate).max(axis=1)
        before = np.minimum(UPPER - q[live], q[live] - LOWER).min(axis=1)
        fraction = np.where(inside, 1.0, before / np.maximum(before + over, 1e-300))
        length[live] += fraction * moved
        tangent[live] = candidate - q[live]
        q[live] = candidate
        looped = (length[live] > 10 * step_rad) & (
            np.linalg.norm(candidate - start[live], axis=1) < step_rad
        )
        for i, p, keep in zip(live.tolist(), candidate, inside, strict=True):
            if keep:
                paths[i].append(p.copy())
        running[live] = inside & ~looped
    assert not running.any()
    return length, [np.asarray(p) for p in paths]


def test_pose_smm_components_agree_with_an_independent_continuation(
    chain: UrdfChain, pose_cases: list
) -> None:
    for _, pose, components in pose_cases:
        points = np.concatenate([c.q_rad for c in components])
        owner = np.concatenate([np.full(len(c.q_rad), i) for i, c in enumerate(components)])
        tree = cKDTree(points)
        middle = np.array([c.q_rad[len(c.q_rad) // 2] for c in components])  # (C, 7)
        after = np.array(
            [c.q_rad[min(len(c.q_rad) // 2 + 1, len(c.q_rad) - 1)] for c in components]
        )
        before = np.array([c.q_rad[max(len(c.q_rad) // 2 - 1, 0)] for c in components])
        both = np.concatenate([middle, middle])
        length, paths = _continue(
            chain, pose, both, np.concatenate([after - before, before - after])
        )
        for i, component in enumerate(components):
            # Both ways from the middle: the whole component, or twice round a loop.
            traced = length[i] + length[i + len(components)]
            expected = component.arc_length_rad * (2 if component.closed else 1)
            assert traced == pytest.approx(expected, rel=0.02, abs=0.12), (i, component.closed)
            walked = np.concatenate([paths[i], paths[i + len(components)]])
            distance, nearest = tree.query(walked)
            # Within a step of the reference's points: it ends up to a step short of a limit.
            assert distance.max() < 0.05
            assert set(owner[nearest].tolist()) == {i}  # neither split nor merged


def test_an_unreachable_pose_has_no_solution() -> None:
    assert panda.pose_smm(np.array([2.0, 0.0, 0.3]), np.eye(3)) == []


@pytest.fixture(scope="module")
def position_cases(chain: UrdfChain) -> list[tuple[np.ndarray, np.ndarray, PositionSmm]]:
    """2 random targets: (generating q (7,), its TCP position (3,), the exact fibre)."""
    cases = []
    for i, q in enumerate(_targets(2, seed=5)):
        position = chain.pose(q[None])[0, :3, 3]
        cases.append((q, position, panda.position_smm(position, num_points=100_000, seed=i)))
    return cases


def test_position_smm_points_are_exact_and_hold_the_target(
    chain: UrdfChain, position_cases: list
) -> None:
    for q_target, position, fibre in position_cases:
        assert np.abs(chain.pose(fibre.q_rad)[:, :3, 3] - position).max() < 1e-9
        assert np.all((fibre.q_rad >= LOWER) & (fibre.q_rad <= UPPER))
        assert fibre.count >= 1 and fibre.share.sum() == pytest.approx(1.0)
        # Its q1..q6 within the grid's link radius (4.5 x 0.079 rad) of a drawn point.
        assert np.linalg.norm(fibre.q_rad[:, :6] - q_target[:6], axis=1).min() < 0.36
        # The label nodes: every drawn point is a node, with the node's component, and
        # the nodes (float32) hold the target too.
        nodes = np.concatenate([fibre.node_q6_rad, np.zeros((len(fibre.node_q6_rad), 1))], 1)
        assert np.abs(chain.pose(nodes)[:, :3, 3] - position).max() < 1e-5
        distance, node = cKDTree(fibre.node_q6_rad).query(fibre.q_rad[:, :6])
        assert distance.max() < 1e-6
        np.testing.assert_array_equal(fibre.node_component[node], fibre.component)


def _walk_on_position_fibre(
    chain: UrdfChain, q_start: np.ndarray, steps: int, seed: int
) -> np.ndarray:
    """(steps, 7) a random walk along the position fibre within the limits (as the iiwa
    test's): 0.03 rad along the position Jacobian's null space, Gauss-Newton back."""
    rng = np.random.default_rng(seed)
    goal = chain.pose(q_start[None])[0, :3, 3]
    q, heading = q_start.copy(), rng.normal(size=7)
    path: list[np.ndarray] = []
    while len(path) < steps:
        null = np.linalg.svd(chain.jacobian(q[None])[0, :3])[2][3:].T  # (7, 4)
        step = null @ (null.T @ heading)
        heading = step / np.linalg.norm(step) + 0.3 * rng.normal(size=7)
        candidate = q + 0.03 * step / np.linalg.norm(step)
        for _ in range(5):
            error = chain.pose(candidate[None])[0, :3, 3] - goal
            candidate = candidate - np.linalg.pinv(chain.jacobian(candidate[None])[0, :3]) @ error
        if np.all((candidate >= LOWER) & (candidate <= UPPER)):
            q = candidate
        path.append(q.copy())
    return np.asarray(path)


def test_a_feasible_walk_along_the_position_fibre_stays_in_one_component(
    chain: UrdfChain, position_cases: list
) -> None:
    for i, (q_target, _, fibre) in enumerate(position_cases):
        path = _walk_on_position_fibre(chain, q_target, steps=200, seed=i)
        assert np.linalg.norm(path[:, :6] - q_target[:6], axis=1).max() > 0.5  # it moved
        nearest = cKDTree(fibre.q_rad[:, :6]).query(path[:, :6])[1]
        assert len(set(fibre.component[nearest].tolist())) == 1


def test_a_straight_walk_joins_two_points_of_one_fibre_and_never_reaches_off_it(
    chain: UrdfChain, position_cases: list
) -> None:
    """The reference's join (`panda.walks_join`, on the DH table) against the test's own
    URDF chain: two points 20 steps apart on a null-space walk of the fibre are joined; a
    configuration 0.3 rad off the fibre (centimetres off the target) is never reached."""
    starts, ends, offs = [], [], []
    rng = np.random.default_rng(3)
    for i, (q_target, position, _) in enumerate(position_cases):
        path = _walk_on_position_fibre(chain, q_target, steps=20, seed=10 + i)
        starts.append(path[0, :6])
        ends.append(path[-1, :6])
        off = path[-1] + rng.normal(size=7) * 0.3 / np.sqrt(7)
        assert np.linalg.norm(chain.pose(off[None])[0, :3, 3] - position) > 0.01
        offs.append(np.clip(off, LOWER, UPPER)[:6])
        assert panda.walks_join(position, np.array(starts[-1:]), np.array(ends[-1:])).all()
        assert not panda.walks_join(position, np.array(starts[-1:]), np.array(offs[-1:])).any()
    assert min(np.linalg.norm(a - b) for a, b in zip(starts, ends, strict=True)) > 0.2


def test_a_component_cut_in_two_by_its_labels_is_joined_again_by_walks(
    position_cases: list,
) -> None:
    """A counted component whose nodes are relabelled as two pieces on either side of its
    median q1 (a split as the link radius makes one) comes back as one; the other
    components keep their membership."""
    for _, position, fibre in position_cases:
        q6 = fibre.q_rad[:5000, :6]
        labels = fibre.component[:5000].copy()
        largest = int(np.bincount(labels).argmax())
        members = labels == largest
        cut = members & (q6[:, 0] > np.median(q6[members, 0]))
        labels[cut] = labels.max() + 1
        joined = panda.join_by_walks(position, q6, labels)
        assert len(set(joined[members].tolist())) == 1
        for other in set(fibre.component[:5000].tolist()) - {largest}:
            assert len(set(joined[fibre.component[:5000] == other].tolist())) == 1
