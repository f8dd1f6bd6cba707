"""references.iiwa14: the DH table and the S-R-S IK ground truth of the iiwa14.

The DH forward kinematics equals the bundled URDF (models/robots/iiwa14.urdf) read by the
float64 URDF chain (references.urdf_chain: Rodrigues and URDF origins, no DH table) to
1e-12 at random configurations, and the DH limits are the URDF's. Everything else is
checked by that URDF chain, not by the DH FK under test: the IK's configurations reach
the pose to 1e-9 on all 8 branches; the configuration that made a target must lie on its
exact SMM; each feasible component stays within the limits and is continuous, also where
it passes next to the shoulder set and q1, q3 swing fast against each other; the 4-D
position SMM is exact and feasible, q7 does not move the position, a feasible walk along
the position fibre stays in one component, the exact points of the singular sets are
exact, and a fibre that cannot reach the shoulder or elbow set (by the link lengths
alone) keeps the sign of q2 and q4 within each component, so its twins stay apart.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from service.manifest import REPO_MODELS_DIR
from training.evaluate.references import iiwa14
from training.evaluate.references.iiwa14 import (
    BRANCHES,
    inverse_kinematics,
    pose_smm,
    position_smm,
    singular_set_points,
)
from training.evaluate.references.rotations import rotation_angle_rad
from training.evaluate.references.urdf_chain import read_chain

# The tests' FK of the iiwa14: its URDF in float64, independent of the DH table under test.
URDF = read_chain(REPO_MODELS_DIR / "robots" / "iiwa14.urdf", "ee")
iiwa14_pose = URDF.pose
LIMITS_RAD = URDF.upper  # symmetric: URDF.lower is -URDF.upper (test_the_dh_table_is_the_urdfs)
# Link lengths of the DH table, for the reach arguments (the DH table is the URDF's).
SHOULDER = iiwa14.SHOULDER_M
UPPER_ARM, FOREARM, WRIST_TO_EE = iiwa14.UPPER_ARM_M, iiwa14.FOREARM_M, iiwa14.WRIST_TO_EE_M


def test_the_dh_table_is_the_urdfs() -> None:
    q = np.random.default_rng(1).uniform(-iiwa14.LIMITS_RAD, iiwa14.LIMITS_RAD, (200, 7))
    np.testing.assert_allclose(iiwa14.dh_pose(q), URDF.pose(q), rtol=0, atol=1e-12)
    np.testing.assert_allclose(iiwa14.dh_pose(q[0]), URDF.pose(q[:1]), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(URDF.upper, iiwa14.LIMITS_RAD)
    np.testing.assert_array_equal(URDF.lower, -iiwa14.LIMITS_RAD)
    # The link lengths the reach arguments use: the shoulder, the elbow and the wrist.
    origins = URDF.frames(np.zeros((1, 7)))[0][0, :, :3, 3]  # (7, 3) joint origins, arm up
    assert origins[1, 2] == pytest.approx(SHOULDER[2], abs=1e-12)
    assert origins[3, 2] - origins[1, 2] == pytest.approx(UPPER_ARM, abs=1e-12)
    assert origins[5, 2] - origins[3, 2] == pytest.approx(FOREARM, abs=1e-12)
    tip = URDF.pose(np.zeros((1, 7)))[0, 2, 3]
    assert tip - origins[5, 2] == pytest.approx(WRIST_TO_EE, abs=1e-12)


def _targets(count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    q = np.random.default_rng(seed).uniform(-LIMITS_RAD, LIMITS_RAD, (count, 7))
    return q, iiwa14_pose(q)


def test_every_branch_reaches_the_pose_by_dh_fk() -> None:
    _, poses = _targets(10, seed=0)
    psi = np.linspace(-np.pi, np.pi, 97, endpoint=False)
    for pose in poses:
        solutions = []
        for branch in BRANCHES:
            q = inverse_kinematics(pose[:3, 3], pose[:3, :3], psi, branch)
            assert q is not None
            reached = iiwa14_pose(q)
            assert np.abs(reached[:, :3, 3] - pose[:3, 3]).max() < 1e-9
            goal = np.broadcast_to(pose[:3, :3], reached[:, :3, :3].shape)
            assert rotation_angle_rad(reached[:, :3, :3], goal).max() < 1e-9
            solutions.append(q)
        # The 8 branches are 8 different configurations at every arm angle.
        stacked = np.stack(solutions)  # (8, K, 7)
        gaps = np.linalg.norm(stacked[:, None] - stacked[None], axis=-1)  # (8, 8, K)
        assert gaps[~np.eye(8, dtype=bool)].min() > 1e-3


def test_an_unreachable_pose_has_no_solution() -> None:
    rotation = np.eye(3)
    assert inverse_kinematics(np.array([2.0, 0, 0.36]), rotation, np.zeros(1), BRANCHES[0]) is None
    assert pose_smm(np.array([2.0, 0, 0.36]), rotation) == []


def test_the_generating_configuration_lies_on_the_exact_smm() -> None:
    q_targets, poses = _targets(10, seed=1)
    for q_target, pose in zip(q_targets, poses, strict=True):
        components = pose_smm(pose[:3, 3], pose[:3, :3], psi_steps=3600)
        nearest = min(np.linalg.norm(c.q_rad - q_target, axis=1).min() for c in components)
        assert nearest < 0.01  # psi step 2 pi / 3600 moves the joints by a few mrad


def test_components_are_feasible_continuous_and_exact() -> None:
    _, poses = _targets(5, seed=2)
    for pose in poses:
        components = pose_smm(pose[:3, 3], pose[:3, :3])
        assert 2 <= len(components) <= 60
        for component in components:
            assert np.all(np.abs(component.q_rad) <= LIMITS_RAD)
            steps = np.linalg.norm(np.diff(component.q_rad, axis=0), axis=1)
            assert steps.max(initial=0.0) <= 0.2
            assert component.arc_length_rad == pytest.approx(steps.sum(), rel=1e-9, abs=0.2)
            reached = iiwa14_pose(component.q_rad)
            assert np.abs(reached[:, :3, 3] - pose[:3, 3]).max() < 1e-9


@pytest.mark.parametrize("q2_rad", [1e-4, 1e-7])
def test_a_component_passing_near_the_shoulder_set_is_whole(q2_rad: float) -> None:
    # Near q2 = 0, q1 and q3 swing by about pi against each other while psi hardly moves:
    # consecutive arm-angle samples are then far apart on one continuous arc. The arc must
    # stay one component, filled with exact points no more than 0.2 rad apart.
    q_target = np.array([0.3, q2_rad, 0.4, -1.2, 0.5, 1.0, 0.2])
    pose = iiwa14_pose(q_target[None])[0]
    components = pose_smm(pose[:3, 3], pose[:3, :3])
    holder = min(components, key=lambda c: np.linalg.norm(c.q_rad - q_target, axis=1).min())
    assert np.linalg.norm(holder.q_rad - q_target, axis=1).min() < 0.1
    assert np.ptp(holder.q_rad[:, 0]) > 2.5  # the swing is inside it
    for component in components:
        steps = np.linalg.norm(np.diff(component.q_rad, axis=0), axis=1)
        assert steps.max(initial=0.0) <= 0.2
        assert np.all(np.abs(component.q_rad) <= LIMITS_RAD)
        reached = iiwa14_pose(component.q_rad)
        assert np.abs(reached[:, :3, 3] - pose[:3, 3]).max() < 1e-6
        assert rotation_angle_rad(reached[:, :3, :3], pose[None, :3, :3]).max() < 1e-6


def test_position_smm_points_are_exact_feasible_and_q7_does_not_move_the_position() -> None:
    q_targets, poses = _targets(3, seed=5)
    for q_target, pose in zip(q_targets, poses, strict=True):
        fibre = position_smm(pose[:3, 3], num_points=5000, seed=0)
        reached = iiwa14_pose(fibre.q_rad)[:, :3, 3]
        assert np.abs(reached - pose[:3, 3]).max() < 1e-9
        assert np.all(np.abs(fibre.q_rad) <= LIMITS_RAD)
        assert fibre.count >= 1 and fibre.share.sum() == pytest.approx(1.0)
        # The premise of drawing q7 freely: joint 7 turns the end effector about its own
        # position (checked by the tests' DH FK, not by the reference's).
        turned = q_target + np.array([0, 0, 0, 0, 0, 0, 1.0])
        np.testing.assert_allclose(iiwa14_pose(turned[None])[0, :3, 3], pose[:3, 3], atol=1e-12)
        # The generating configuration's q1..q6 lies among the fibre's points.
        assert np.linalg.norm(fibre.q_rad[:, :6] - q_target[:6], axis=1).min() < 0.5
        # The label nodes: every drawn point is a node, with the node's component, and
        # the nodes are exact too.
        nodes = np.concatenate([fibre.node_q6_rad, np.zeros((len(fibre.node_q6_rad), 1))], 1)
        assert np.abs(iiwa14_pose(nodes)[:, :3, 3] - pose[:3, 3]).max() < 1e-5  # float32
        distance, node = cKDTree(fibre.node_q6_rad).query(fibre.q_rad[:, :6])
        assert distance.max() < 1e-6
        np.testing.assert_array_equal(fibre.node_component[node], fibre.component)


def _walk_on_position_fibre(q_start: np.ndarray, steps: int, seed: int) -> np.ndarray:
    """(steps, 7) a random walk along the position fibre within the limits, by the DH FK.

    Each step moves 0.03 rad along the null space of the position Jacobian (central
    differences), in a direction that drifts at random, and returns to the fibre by
    Gauss-Newton; steps that leave the limits are refused. Every point is joined to the
    start by a feasible path.
    """
    rng = np.random.default_rng(seed)
    goal = iiwa14_pose(q_start[None])[0, :3, 3]

    def jacobian(q: np.ndarray) -> np.ndarray:
        shifted = q[None] + 1e-6 * np.concatenate([np.eye(7), -np.eye(7)])
        positions = iiwa14_pose(shifted)[:, :3, 3]
        return ((positions[:7] - positions[7:]) / 2e-6).T  # (3, 7)

    q, heading = q_start.copy(), rng.normal(size=7)
    path: list[np.ndarray] = []
    while len(path) < steps:
        _, _, vt = np.linalg.svd(jacobian(q))
        null = vt[3:].T  # (7, 4)
        step = null @ (null.T @ heading)  # keep going the same way, so the walk travels
        heading = step / np.linalg.norm(step) + 0.3 * rng.normal(size=7)
        candidate = q + 0.03 * step / np.linalg.norm(step)
        for _ in range(5):
            error = iiwa14_pose(candidate[None])[0, :3, 3] - goal
            candidate = candidate - np.linalg.pinv(jacobian(candidate)) @ error
        if np.all(np.abs(candidate) <= LIMITS_RAD):
            q = candidate
        path.append(q.copy())
    return np.asarray(path)


def test_a_feasible_walk_along_the_position_fibre_stays_in_one_component() -> None:
    # Components are separated by the limits only: a continuous feasible path (here a
    # random walk through singular sets and across branches) never changes component.
    q_targets, poses = _targets(4, seed=11)
    for i, (q_target, pose) in enumerate(zip(q_targets, poses, strict=True)):
        fibre = position_smm(pose[:3, 3], num_points=200_000, seed=i)
        path = _walk_on_position_fibre(q_target, steps=300, seed=i)
        assert np.abs(iiwa14_pose(path)[:, :3, 3] - pose[:3, 3]).max() < 1e-9
        assert np.linalg.norm(path[:, :6] - q_target[:6], axis=1).max() > 0.5  # it moved
        nearest = cKDTree(fibre.q_rad[:, :6]).query(path[:, :6])[1]
        assert len(set(fibre.component[nearest].tolist())) == 1


def test_singular_set_points_are_exact_and_on_their_set() -> None:
    _, poses = _targets(20, seed=21)
    seen: set[int] = set()
    for pose in poses:
        for joint, q6 in singular_set_points(pose[:3, 3]).items():
            seen.add(joint)
            q = np.concatenate([q6, np.zeros((len(q6), 1))], axis=1)
            assert np.abs(iiwa14_pose(q)[:, :3, 3] - pose[:3, 3]).max() < 1e-7
            assert np.abs(q6[:, joint]).max() < 2e-3  # on the set (q4: 1e-7 m short)
    assert seen == {1, 3, 5}


def test_twins_stay_apart_where_the_fibre_cannot_reach_the_shoulder_or_elbow_set() -> None:
    # With q2 = 0 the elbow sits 0.42 m above the shoulder, so the end effector is at
    # most 0.40 + 0.126 m from there; with q4 = 0 it is at least 0.82 - 0.126 m from
    # the shoulder. This target violates both: no path on its fibre changes the sign of
    # q2 or of q4, so the shoulder and elbow twins are separate components, four in all,
    # however near q2 = 0 the fibre comes (a contact rule by distance alone joins them).
    q = np.array([-1.8321, 0.3116, -2.7316, 1.2636, 2.7301, 1.4829, -2.7446])
    position = iiwa14_pose(q[None])[0, :3, 3]
    elbow_up = SHOULDER + np.array([0.0, 0.0, UPPER_ARM])
    assert np.linalg.norm(position - elbow_up) > FOREARM + WRIST_TO_EE
    assert np.linalg.norm(position - SHOULDER) < UPPER_ARM + FOREARM - WRIST_TO_EE
    assert set(singular_set_points(position)) == {5}
    fibre = position_smm(position, num_points=20_000, seed=0)
    assert np.abs(fibre.q_rad[:, 1]).min() < 0.15  # the fibre does come near q2 = 0
    for component in np.unique(fibre.component):
        members = fibre.q_rad[fibre.component == component]
        assert len(set(np.sign(members[:, 1]).tolist())) == 1
        assert len(set(np.sign(members[:, 3]).tolist())) == 1
    signs = {(int(np.sign(a)), int(np.sign(b))) for a, b in fibre.q_rad[:, [1, 3]]}
    assert fibre.count == len(signs) == 4
