"""references.axis: the axis task's exact SMMs (the UR5's by eaik over psi, the iiwa14's by
ssik's charts over psi), checked independently.

By the float64 URDF chain (references.urdf_chain) of example-robot-data's UR5 and by the
iiwa14's DH table: every exact configuration reaches the target position within 1e-9 m
with the tool axis within 1e-7 rad of the target axis (the iiwa14's within ssik's 1e-7
at a fold), and the configuration that made
the target lies on the SMM. With the flange's z axis (the UR5's wrist-3 axis) each IK
branch is one loop of q6 alone, 2 pi long. With a tilted tool axis, every joint moves
along the UR5's 1-D SMM: a predictor-corrector continuation along the Jacobian's null
space (independent of the sweep) from the generating configuration comes back round
its loop, every point of it on one exact component, over that component's length.
On the iiwa14's 2-D SMM a random walk in the null space, inside the limits, stays on
the component it starts on.
"""

from __future__ import annotations

import numpy as np
import pytest

from service.manifest import REPO_MODELS_DIR
from service.pipeline.joint_space import JointBox, wrap_to_pi
from training.evaluate.references import axis, iiwa14
from training.evaluate.references.axis import AxisSmm
from training.evaluate.references.urdf_chain import UrdfChain

FLANGE = np.array([0.0, 0.0, 1.0])
TILTED = np.array([0.6, 0.0, 0.8])


@pytest.fixture(scope="module")
def ur5() -> UrdfChain:
    return axis.ur5_chain()


def test_the_bundled_ur5_is_example_robot_data_s_with_the_flange_as_end_effector(
    ur5: UrdfChain,
) -> None:
    """Six revolute joints, every one turning a full circle or more (the elbow exactly
    one), and tool0's z axis along the wrist-3 joint's axis: the axis task's tool axis."""
    assert len(ur5.movable) == 6
    np.testing.assert_allclose(
        ur5.upper - ur5.lower, [4 * np.pi] * 2 + [2 * np.pi] + [4 * np.pi] * 3
    )
    frames, pose = ur5.frames(np.random.default_rng(0).uniform(-3, 3, (5, 6)))
    wrist_3 = np.einsum("bij,j->bi", frames[:, 5, :3, :3], ur5.movable[5].axis)
    np.testing.assert_allclose(pose[:, :3, 2], wrist_3, atol=1e-12)
    assert (REPO_MODELS_DIR / "robots" / "ur5" / "collision" / "wrist3.stl").is_file()


def _axis_errors(
    chain_pose: np.ndarray, position: np.ndarray, direction: np.ndarray, tool: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(P,) position errors (m) and tool-axis angles (rad) of poses (P, 4, 4)."""
    reached = chain_pose[:, :3, :3] @ tool
    cosine = np.clip(reached @ direction, -1.0, 1.0)
    return np.linalg.norm(chain_pose[:, :3, 3] - position, axis=1), np.arccos(cosine)


def _label(smm: AxisSmm, q: np.ndarray, periodic: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Q,) the nearest exact point's component and distance (joint metric)."""
    box = JointBox.covering(np.concatenate([smm.q_rad, q]), periodic, margin_rad=10.0)
    distance, nearest = box.tree(smm.q_rad).query(box.points(q))
    return smm.component[nearest], distance


def test_ur5_slices_are_exact_and_hold_the_configuration(ur5: UrdfChain) -> None:
    """Each pose's IK rows reach it to 1e-9 by the URDF chain, and one is the generating
    configuration (wrapped) to 1e-9."""
    for q in np.random.default_rng(1).uniform(-np.pi, np.pi, (20, 6)):
        pose = ur5.pose(q[None])[0]
        exact = axis.ur5_slice(pose)
        assert 1 <= len(exact.q_rad) <= 8
        np.testing.assert_allclose(
            ur5.pose(exact.q_rad), np.broadcast_to(pose, (len(exact.q_rad), 4, 4)), atol=1e-9
        )
        assert np.linalg.norm(wrap_to_pi(exact.q_rad - q), axis=1).min() < 1e-9


def test_ur5_flange_axis_smm_is_one_q6_loop_per_ik_branch(ur5: UrdfChain) -> None:
    """With the wrist-3 axis as tool axis, turning about it is turning q6: one component
    per IK branch of the pose, each 2 pi long, its points exact."""
    for q in np.random.default_rng(2).uniform(-np.pi, np.pi, (6, 6)):
        pose = ur5.pose(q[None])[0]
        smm = axis.ur5_axis_smm(pose[:3, 3], pose[:3, 2], FLANGE)
        assert smm.count == len(axis.ur5_slice(pose).q_rad)
        np.testing.assert_allclose(smm.size, 2 * np.pi, rtol=1e-6)
        position_error, angle = _axis_errors(ur5.pose(smm.q_rad), pose[:3, 3], pose[:3, 2], FLANGE)
        assert position_error.max() < 1e-9 and angle.max() < 1e-7
        for c in range(smm.count):  # q1..q5 constant on each loop
            assert np.ptp(smm.q_rad[smm.component == c, :5], axis=0).max() < 1e-9


def _continue_on_axis_fibre(
    chain: UrdfChain,
    position: np.ndarray,
    direction: np.ndarray,
    tool: np.ndarray,
    start: np.ndarray,
    step_rad: float = 0.02,
    max_steps: int = 3000,
) -> tuple[np.ndarray, float]:
    """Predictor-corrector round the UR5's 1-D axis fibre from `start` (6,): the tangent
    is the null vector of [J_p; (z_i x a)], Newton (pseudo-inverse) back onto position and
    axis; stops back at the start (every joint turns a full circle). Points and length."""
    q, previous = start.copy(), None
    points, length = [q.copy()], 0.0

    def stacked(q_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pose = chain.pose(q_rad[None])[0]
        jacobian = chain.jacobian(q_rad[None])[0]
        a = pose[:3, :3] @ tool
        turn = np.cross(jacobian[3:].T, a).T  # (3, 6): z_i x a
        error = np.concatenate([position - pose[:3, 3], direction - a])
        return np.concatenate([jacobian[:3], turn]), error

    for _ in range(max_steps):
        matrix, _ = stacked(q)
        null = np.linalg.svd(matrix)[2][-1]
        if previous is not None and null @ previous < 0:
            null = -null
        candidate = q + step_rad * null
        for _ in range(4):
            matrix, error = stacked(candidate)
            candidate = candidate + np.linalg.pinv(matrix, rcond=1e-10) @ error
        length += float(np.linalg.norm(candidate - q))
        previous, q = candidate - q, candidate
        points.append(q.copy())
        if length > 10 * step_rad and np.linalg.norm(wrap_to_pi(q - start)) < step_rad:
            return np.asarray(points), length
    raise AssertionError("the continuation did not come back round its loop")


def test_ur5_tilted_axis_components_agree_with_an_independent_continuation(
    ur5: UrdfChain,
) -> None:
    """Tool axis tilted off the wrist: every joint moves along the SMM. Every exact point
    is exact; the loop continued from the generating configuration lies on one exact
    component (each point within 0.026 rad of one of its points, spaced 0.05 at most)
    and is as long as it (2 %), so the sweep neither splits nor merges it."""
    for q in np.random.default_rng(3).uniform(-np.pi, np.pi, (4, 6)):
        pose = ur5.pose(q[None])[0]
        direction = pose[:3, :3] @ TILTED
        smm = axis.ur5_axis_smm(pose[:3, 3], direction, TILTED)
        position_error, angle = _axis_errors(ur5.pose(smm.q_rad), pose[:3, 3], direction, TILTED)
        assert position_error.max() < 1e-9 and angle.max() < 1e-7
        loop, length = _continue_on_axis_fibre(ur5, pose[:3, 3], direction, TILTED, q)
        labels, distance = _label(smm, wrap_to_pi(loop), np.ones(6, bool))
        # The sweep's points are at most 0.05 rad apart: each loop point is within half that.
        assert len(np.unique(labels)) == 1 and distance.max() < 0.026
        assert length == pytest.approx(smm.size[labels[0]], rel=0.02)


LIMITS = iiwa14.LIMITS_RAD


def _dh_axis_jacobian(q: np.ndarray) -> np.ndarray:
    """(5, 7) the position rows and two axis rows of the iiwa14's DH chain, by central
    differences of the flange's position and z axis (rank 5 off singularities)."""
    step = 1e-6
    columns = []
    for i in range(7):
        dq = np.zeros(7)
        dq[i] = step
        plus, minus = iiwa14.dh_pose((q + dq)[None])[0], iiwa14.dh_pose((q - dq)[None])[0]
        columns.append(np.concatenate([plus[:3, 3] - minus[:3, 3], plus[:3, 2] - minus[:3, 2]]))
    return np.stack(columns, axis=1) / (2 * step)  # (6, 7), rank 5


def test_iiwa14_axis_smm_is_exact_and_a_walk_on_it_stays_in_one_component() -> None:
    """Points exact by the DH table; the generating configuration within the sweep's
    join of a point; a random walk in the 2-D null space (inside the limits, projected
    back) stays on the component it starts on."""
    rng = np.random.default_rng(4)
    for q in rng.uniform(-0.8 * LIMITS, 0.8 * LIMITS, (2, 7)):
        pose = iiwa14.dh_pose(q[None])[0]
        smm = axis.iiwa14_axis_smm(pose[:3, 3], pose[:3, 2], FLANGE, -LIMITS, LIMITS)
        position_error, angle = _axis_errors(
            iiwa14.dh_pose(smm.q_rad), pose[:3, 3], pose[:3, 2], FLANGE
        )
        # ssik's closed form is exact to about 1e-7 at a fold of its chart coordinate.
        assert position_error.max() < 1e-7 and angle.max() < 1e-6
        assert np.all(np.abs(smm.q_rad) <= LIMITS + 1e-9)
        start_label, start_distance = _label(smm, q[None], np.zeros(7, bool))
        assert start_distance[0] < axis.SPACING_RAD + 2 * np.pi / axis.IIWA14_PSI_STEPS
        walk, current = [q], q.copy()
        for _ in range(150):
            null = np.linalg.svd(_dh_axis_jacobian(current))[2][-2:]  # (2, 7)
            candidate = current + 0.03 * (rng.normal(size=2) @ null)
            for _ in range(4):
                reached = iiwa14.dh_pose(candidate[None])[0]
                error = np.concatenate([pose[:3, 3] - reached[:3, 3], pose[:3, 2] - reached[:3, 2]])
                candidate = (
                    candidate + np.linalg.pinv(_dh_axis_jacobian(candidate), rcond=1e-8) @ error
                )
            if np.all(np.abs(candidate) < LIMITS):
                current = candidate
                walk.append(current)
        labels, distance = _label(smm, np.asarray(walk), np.zeros(7, bool))
        assert len(walk) > 50
        assert np.all(labels == start_label[0]) and distance.max() < 0.1
