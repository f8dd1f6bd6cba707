"""native: the compiled kernels answer as the numpy kernels, pytorch-kinematics and scipy
do. Chain kinematics: for every bundled arm's chain.json, at configurations uniform over
several turns, the compiled kernel equals the numpy kernel it replaced
(tests/support/numpy_kernels.py) and pytorch-kinematics (FK and Jacobian of the URDF, what
kinematics.onnx is exported from) to 1e-12. Rotation error: log(R* R^T) equals scipy's
rotation vector at every angle up to pi (both sides of the 150-degree switch) to 1e-12, and
a non-rotation is NaN in its own row. DLS step: on the arms' own Jacobians (pose and
position rows) it equals the numpy step (LAPACK's solve) to 1e-12 relative to the step, and
the closed form J^T (J J^T + d^2 I)^-1 e; a singular system with zero damping takes the
pseudo-inverse's step and a non-finite row is NaN in its own row. Wrong shapes and sizes
beyond the kernels' fixed bounds are refused with the valid range named. URDF joint frames
equal the numpy frames (Rodrigues on whole columns) and end, times the tip, at the chain
kinematics' end effector. Self-clearance of the iiwa14's and Panda's spheres equals the
numpy two-pass minimum and a brute force over every sphere pair, and the same at joint
values (each row placing its own frames) bitwise. The bordered solve [J; t^T] x = b of the
trace's corrector and tangent equals LAPACK's, NaN where singular. The task residual (FK and
task error in one pass) equals `task_error` of the chain kernel bitwise and of
kinematics.onnx to 1e-12, for pose and position tasks; for the axis task its two rows equal
the numpy ones to 1e-12, their norm is the angle between the tool axis and its target (pi
when opposite), and their Jacobian is -de/dq by central differences. The compiled Newton
steps (DLS, stopping at a tolerance, locked joints, bordered on a tangent) end where the
numpy steps do, to 1e-12, and rows marked fresh (evaluated first) where the same rows
measured beforehand do, to the bit. The smallest singular value (one-sided Jacobi) equals
LAPACK's SVD to 1e-12, singular and near-singular Jacobians included, and the bounded search
for the least over many rows finds exactly the least. GJK between placed hulls takes
convex.py's numpy steps (1e-12) on the robots' own hulls, the refined self-clearance at
joint values equals robot.py's numpy passes (1e-12), and the least distance from samples to
the path segments beside their candidate points equals the numpy segments' (1e-12) and, with
every point a candidate, a brute force over every segment; each query's nearest point of its
own group is the brute-force argmin of the joint metric, -1 for a group with no point, and
its k nearest points are the brute-force order; the roadmap's nearest node of each other
component and links within a radius are the brute-force ones in the KD-tree box's metric,
and its components merged along new edges are scipy's, numbered by lowest node. The trace's
tangent signs, Hermite guesses, choice of the steps to refine near the limits and last pass
over its dense points equal the numpy steps bitwise. (The trace's compiled walk and closest
approach of two strands are pinned in tests/service/pipeline/connect/.)"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial.transform import Rotation

from service.manifest import (
    CHAIN_FILE,
    COLLISION_FILE,
    KINEMATICS_FILE,
    REPO_MODELS_DIR,
    ChainSpec,
    CollisionSpec,
    TaskSpec,
)
from service.models.chain import SerialChainKinematics
from service.models.registry import load_model
from service.models.sessions import OnnxKinematics, open_session
from service.pipeline import native
from service.pipeline.collision.convex import hull_support, separation_m
from service.pipeline.collision.frames import chain_frames
from service.pipeline.collision.robot import RobotSpheres
from service.pipeline.correction import residual_of, task_error
from service.pipeline.fibre import Fibre, Projection, evaluate, newton, project, unit_tangent
from service.pipeline.joint_space import joint_distance
from service.pipeline.rotations import rotation_log
from service.pipeline.targets import Target, kernel_orientation
from tests.support.chains import pytorch_kinematics_answer
from tests.support.numpy_kernels import NumpyChainKinematics, NumpyStepsKinematics
from tests.support.numpy_kernels import along as numpy_along
from tests.support.numpy_kernels import chain_frames as numpy_chain_frames
from tests.support.numpy_kernels import dls_step as numpy_dls_step
from tests.support.numpy_kernels import hermite as numpy_hermite
from tests.support.numpy_kernels import nearest_segment as numpy_nearest_segment
from tests.support.numpy_kernels import segment_distance as numpy_segment_distance
from tests.support.numpy_kernels import self_clearance_m as numpy_self_clearance_m
from tests.support.numpy_kernels import settle_dense as numpy_settle_dense
from tests.support.numpy_kernels import steps_near_limits as numpy_steps_near_limits
from training.evaluate.targets import uniform_configurations

MODELS = ["iiwa14-pose", "panda-pose", "planar3r-position"]
URDF = {"iiwa14-pose": "iiwa14", "panda-pose": "panda", "planar3r-position": "planar3r"}


def chain(model: str) -> SerialChainKinematics:
    return SerialChainKinematics.from_file(REPO_MODELS_DIR / model / CHAIN_FILE)


def turns(n: int, count: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-3 * np.pi, 3 * np.pi, (count, n))


@pytest.mark.parametrize("model", MODELS)
def test_chain_equals_the_numpy_kernel(model: str) -> None:
    kinematics = chain(model)
    q = turns(kinematics.joint_count, 3000, seed=0)
    compiled = kinematics(q)
    reference = NumpyChainKinematics(kinematics.spec)(q)
    for a, b in (
        (compiled.position_m, reference.position_m),
        (compiled.rotation, reference.rotation),
        (compiled.jacobian, reference.jacobian),
    ):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


@pytest.mark.parametrize("model", MODELS)
def test_chain_equals_pytorch_kinematics(model: str) -> None:
    kinematics = chain(model)
    q = turns(kinematics.joint_count, 500, seed=1)
    answer = kinematics(q)
    urdf = REPO_MODELS_DIR / "robots" / f"{URDF[model]}.urdf"
    expected = pytorch_kinematics_answer(urdf, kinematics.spec.end_effector_link, q)
    for a, e in zip((answer.position_m, answer.rotation, answer.jacobian), expected, strict=True):
        np.testing.assert_allclose(a, e, rtol=0, atol=1e-12)


def test_rotation_error_equals_scipy_at_every_angle() -> None:
    rng = np.random.default_rng(2)
    target = Rotation.random(random_state=3).as_matrix()
    # Errors of every size up to just below pi, on random axes: both sides of 150 degrees.
    angle = np.concatenate([np.linspace(0.0, np.pi - 1e-6, 2000), [1e-12, 2.61799, 2.61800]])
    axis = rng.normal(size=(len(angle), 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    expected = axis * angle[:, None]
    # R = exp(-[e]) R*, so that log(R* R^T) = e.
    rotation = Rotation.from_rotvec(-expected).as_matrix() @ target
    error = native.rotation_error(target, rotation)
    np.testing.assert_allclose(error, expected, rtol=0, atol=1e-12)
    # And the numpy logarithm (per-row targets) agrees.
    per_row = rotation_log(target[None] @ np.swapaxes(rotation, 1, 2))
    np.testing.assert_allclose(error, per_row, rtol=0, atol=1e-12)


def test_rotation_error_of_a_non_rotation_is_nan_in_its_row_only() -> None:
    target = np.eye(3)
    rotation = Rotation.random(5, random_state=4).as_matrix()
    rotation[1, 0, 0] = np.nan
    rotation[3] *= -1.0  # determinant -1
    error = native.rotation_error(target, rotation)
    bad = np.array([False, True, False, True, False])
    assert np.all(np.isnan(error[bad])) and np.all(np.isfinite(error[~bad]))
    np.testing.assert_allclose(
        error[~bad], Rotation.from_matrix(rotation[~bad].transpose(0, 2, 1)).as_rotvec(), atol=1e-12
    )


@pytest.mark.parametrize(
    ("model", "rows"),
    [
        ("iiwa14-pose", slice(None)),
        ("iiwa14-pose", slice(0, 3)),
        ("planar3r-position", slice(0, 2)),
    ],
)
def test_dls_step_equals_the_numpy_step_on_real_jacobians(model: str, rows: slice) -> None:
    kinematics = chain(model)
    q = turns(kinematics.joint_count, 2000, seed=5)
    jacobian = np.ascontiguousarray(kinematics(q).jacobian[:, rows])  # (B, m, n)
    error = np.random.default_rng(6).normal(scale=0.05, size=jacobian.shape[:2])  # (B, m)
    damping = 1e-3
    step = native.dls_step(jacobian, error, damping)
    reference = numpy_dls_step(jacobian, error, damping)
    # Both solvers are backward stable: they differ by at most a few eps * cond(G) * |dq|,
    # G = J J^T + d^2 I; where G is well conditioned, by 1e-12 at most.
    gram = jacobian @ np.swapaxes(jacobian, 1, 2) + damping**2 * np.eye(jacobian.shape[1])
    condition = np.linalg.cond(gram)  # (B,)
    scale = np.maximum(np.linalg.norm(reference, axis=1), 1.0)  # (B,)
    difference = np.linalg.norm(step - reference, axis=1)  # (B,)
    assert np.all(difference <= 64 * np.finfo(float).eps * condition * scale)
    well = condition < 1e3
    assert well.mean() > 0.5
    assert np.all(difference[well] <= 1e-12 * scale[well])
    # The closed form, row by row.
    for b in range(0, len(q), 199):
        j, e = jacobian[b], error[b]
        closed = j.T @ np.linalg.solve(j @ j.T + damping**2 * np.eye(len(e)), e)
        np.testing.assert_allclose(step[b], closed, rtol=1e-10, atol=1e-14)


def test_dls_step_singular_and_non_finite_rows() -> None:
    rng = np.random.default_rng(7)
    jacobian = rng.normal(size=(4, 6, 7))
    error = rng.normal(size=(4, 6))
    jacobian[1, :2] = 0.0  # rank 4: J J^T singular without damping
    jacobian[2, 0, 0] = np.inf
    error[3, 5] = np.nan
    step = native.dls_step(jacobian, error, 0.0)
    assert np.all(np.isnan(step[2])) and np.all(np.isnan(step[3]))
    np.testing.assert_allclose(step[1], np.linalg.pinv(jacobian[1]) @ error[1], atol=1e-12)
    np.testing.assert_allclose(
        step[0], np.linalg.solve(jacobian[0] @ jacobian[0].T, error[0]) @ jacobian[0], rtol=1e-10
    )


def test_shapes_beyond_the_kernels_bounds_are_refused() -> None:
    with pytest.raises(ValueError, match="the kernel takes 1 to 64"):
        native.chain_kinematics(np.zeros((65, 4, 4)), np.eye(4), np.zeros((1, 65)))
    with pytest.raises(ValueError, match=r"q_rad has shape \(2, 3\); expected \(2, 7\)"):
        native.chain_kinematics(np.tile(np.eye(4), (7, 1, 1)), np.eye(4), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="the kernel takes 1 to 6"):
        native.dls_step(np.zeros((1, 7, 7)), np.zeros((1, 7)), 1e-3)
    with pytest.raises(ValueError, match="65 bodies; the kernels take at most 64"):
        native.self_clearance_m(
            np.zeros((1, 65, 3, 3)), np.zeros((1, 65, 3)), np.zeros((65, 1, 3)),
            np.ones((65, 1)), np.ones(65, dtype=np.int64), np.zeros((65, 3)), np.ones(65),
            np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64),
        )  # fmt: skip
    with pytest.raises(ValueError, match="a walk needs n - 1 task rows"):
        native.walk(
            np.tile(np.eye(4), (7, 1, 1)), np.eye(4), [0, 1, 2], np.zeros(3), None,
            np.zeros((2, 7)), np.zeros((2, 7)), np.zeros((2, 3, 7)),
            native.WalkRules(0.15, 1, 10, 1.1, 0.05, 0.05), 1e-3, np.inf,
        )  # fmt: skip
    for batch in (0, 1):
        position, rotation, jacobian = native.chain_kinematics(
            np.tile(np.eye(4), (3, 1, 1)), np.eye(4), np.zeros((batch, 3))
        )
        assert (position.shape, rotation.shape, jacobian.shape) == (
            (batch, 3),
            (batch, 3, 3),
            (batch, 6, 3),
        )
        assert native.dls_step(np.zeros((batch, 2, 3)), np.zeros((batch, 2)), 1e-3).shape == (
            batch,
            3,
        )


COLLISION_MODELS = ["iiwa14-pose", "panda-pose"]


def robot_spheres(model: str) -> RobotSpheres:
    chain_spec = ChainSpec.model_validate_json((REPO_MODELS_DIR / model / CHAIN_FILE).read_bytes())
    spec = CollisionSpec.model_validate_json(
        (REPO_MODELS_DIR / model / COLLISION_FILE).read_bytes()
    )
    return RobotSpheres.of(chain_spec, spec)


@pytest.mark.parametrize("model", [*COLLISION_MODELS, "planar3r-position"])
def test_frames_equal_the_numpy_frames_and_the_chain_kinematics(model: str) -> None:
    kinematics = chain(model)
    q = turns(kinematics.joint_count, 2000, seed=8)
    frames = chain_frames(kinematics.spec, q)
    np.testing.assert_allclose(frames, numpy_chain_frames(kinematics.spec, q), rtol=0, atol=1e-12)
    # The last frame times the tip is the end effector of the chain kinematics.
    tip = frames[:, -1] @ np.asarray(kinematics.spec.tip)
    answer = kinematics(q)
    np.testing.assert_allclose(tip[:, :3, 3], answer.position_m, rtol=0, atol=1e-12)
    np.testing.assert_allclose(tip[:, :3, :3], answer.rotation, rtol=0, atol=1e-12)


@pytest.mark.parametrize("model", COLLISION_MODELS)
def test_self_clearance_equals_the_numpy_two_passes_and_brute_force(model: str) -> None:
    robot = robot_spheres(model)
    q = turns(len(robot.chain.joints), 3000, seed=9)
    placed = robot.place(q)
    clearance = robot.self_clearance_m(placed)
    np.testing.assert_allclose(clearance, numpy_self_clearance_m(robot, placed), rtol=0, atol=1e-12)
    assert (clearance < 0).any() and (clearance > 0).any()  # both sides of contact occur
    # Brute force over every own sphere pair of every checked body pair, on 50 rows.
    for row in range(50):
        least = np.inf
        for a, b in zip(robot.pair_a, robot.pair_b, strict=True):
            ca = placed.spheres(np.array([row]), np.array([a]))[0, : robot.own_spheres[a]]
            cb = placed.spheres(np.array([row]), np.array([b]))[0, : robot.own_spheres[b]]
            gap = np.linalg.norm(ca[:, None] - cb[None], axis=2)
            gap -= robot.radius_m[a, : len(ca), None] + robot.radius_m[b, None, : len(cb)]
            least = min(least, float(gap.min()))
        assert abs(clearance[row] - least) <= 1e-12
    # At joint values, each row placing its own frames: bitwise the same numbers, NaN rows
    # in their own row.
    q[5, 1] = np.nan
    at_q = robot.self_clearance_at_m(q)
    np.testing.assert_array_equal(at_q, robot.self_clearance_m(robot.place(q)))
    assert np.isnan(at_q[5]) and np.isfinite(np.delete(at_q, 5)).all()


def test_self_clearance_without_pairs_is_infinite_and_nan_rows_stay_nan() -> None:
    robot = robot_spheres("iiwa14-pose")
    q = turns(len(robot.chain.joints), 4, seed=10)
    q[2, 3] = np.nan
    clearance = robot.self_clearance_m(robot.place(q))
    assert np.isnan(clearance[2]) and np.all(np.isfinite(clearance[[0, 1, 3]]))
    none = native.self_clearance_m(
        *(np.zeros((4, 2, 3, 3)), np.zeros((4, 2, 3))), np.zeros((2, 1, 3)), np.ones((2, 1)),
        np.ones(2, dtype=np.int64), np.zeros((2, 3)), np.ones(2),
        np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64),
    )  # fmt: skip
    assert np.all(np.isinf(none))


@pytest.mark.parametrize(
    ("model", "rows"), [("iiwa14-pose", slice(0, 6)), ("planar3r-position", slice(0, 2))]
)
def test_bordered_solve_equals_lapack_on_corrector_systems(model: str, rows: slice) -> None:
    """[J; t^T] x = [e; 0] with t the fibre's tangent (the corrector's system), and
    [J; t^T] x = [0; 1] (the tangent's): LAPACK's solve to 1e-12 relative to |x|."""
    kinematics = chain(model)
    q = turns(kinematics.joint_count, 2000, seed=11)
    jacobian = np.ascontiguousarray(kinematics(q).jacobian[:, rows])  # (B, n - 1, n)
    batch, m, _ = jacobian.shape
    tangent = np.linalg.qr(np.swapaxes(jacobian, 1, 2), mode="complete")[0][:, :, -1]  # (B, n)
    for top, last in (
        (np.random.default_rng(12).normal(size=(batch, m)), 0.0),
        (np.zeros((batch, m)), 1.0),
    ):
        rhs = np.concatenate([top, np.full((batch, 1), last)], axis=1)
        x = native.bordered_solve(jacobian, tangent, rhs)
        system = np.concatenate([jacobian, tangent[:, None]], axis=1)
        expected = np.linalg.solve(system, rhs[..., None])[..., 0]
        condition = np.linalg.cond(system)
        scale = np.maximum(np.linalg.norm(expected, axis=1), 1.0)
        difference = np.linalg.norm(x - expected, axis=1)
        assert np.all(difference <= 64 * np.finfo(float).eps * condition * scale)
        well = condition < 1e3
        assert well.mean() > 0.5 and np.all(difference[well] <= 1e-12 * scale[well])


def test_bordered_solve_leaves_nan_rows_where_singular_or_not_finite() -> None:
    rng = np.random.default_rng(13)
    jacobian = rng.normal(size=(4, 2, 3))
    border = rng.normal(size=(4, 3))
    rhs = rng.normal(size=(4, 3))
    border[1] = jacobian[1, 0]  # two equal rows: singular
    jacobian[2, 1, 2] = np.nan
    rhs[3, 0] = np.inf
    x = native.bordered_solve(jacobian, border, rhs)
    assert np.all(np.isnan(x[1:])) and np.all(np.isfinite(x[0]))
    np.testing.assert_allclose(np.concatenate([jacobian[0], border[:1]]) @ x[0], rhs[0], atol=1e-12)
    with pytest.raises(ValueError, match=r"the kernel takes \(n - 1, n\)"):
        native.bordered_solve(np.zeros((1, 3, 3)), np.zeros((1, 3)), np.zeros((1, 3)))


@pytest.mark.parametrize(
    ("model", "axes", "orientation"),
    [
        ("iiwa14-pose", [0, 1, 2], True),
        ("iiwa14-pose", [0, 1, 2], False),
        ("planar3r-position", [0, 1], False),
    ],
)
def test_task_residual_equals_the_task_error_of_the_kinematics(
    model: str, axes: list[int], orientation: bool
) -> None:
    """One compiled pass gives `task_error` of the chain kinematics, and of kinematics.onnx
    (what pytorch-kinematics exported) to 1e-12; `residual_of` takes it for a chain."""
    kinematics = chain(model)
    q = turns(kinematics.joint_count, 1000, seed=14)
    task = TaskSpec(
        name="pose" if orientation else "position", position_axes=axes, orientation=orientation
    )
    rotation = Rotation.random(random_state=15).as_matrix() if orientation else None
    target = Target(
        position_m=np.array([0.3, -0.2, 0.5])[: len(axes)],
        rotation=rotation,
        condition=np.zeros(1, np.float32),
    )
    error, jacobian = native.task_residual(
        kinematics.fixed, kinematics.tip, q, axes, target.position_m, rotation
    )
    expected_error, expected_jacobian = task_error(kinematics(q), target, task)
    np.testing.assert_array_equal(error, expected_error)
    np.testing.assert_array_equal(jacobian, expected_jacobian)
    onnx = OnnxKinematics(open_session(REPO_MODELS_DIR / model / KINEMATICS_FILE, threads=1))
    onnx_error, onnx_jacobian = task_error(onnx(q), target, task)
    np.testing.assert_allclose(error, onnx_error, rtol=0, atol=1e-12)
    np.testing.assert_allclose(jacobian, onnx_jacobian, rtol=0, atol=1e-12)
    compiled = residual_of(kinematics, target, task)(q)
    np.testing.assert_array_equal(compiled[0], error)
    through = residual_of(onnx, target, task)(q)  # not a chain: through the kinematics
    np.testing.assert_array_equal(through[0], onnx_error)


def reached_target(
    model: str, seed: int
) -> tuple[SerialChainKinematics, TaskSpec, Target, np.ndarray]:
    """The model's chain, its task (pose or position), and the target that a configuration
    drawn over several turns (seed) reaches, with that configuration (1, n)."""
    kinematics = chain(model)
    task = TaskSpec(
        name="pose" if model == "iiwa14-pose" else "position",
        position_axes=[0, 1, 2] if model == "iiwa14-pose" else [0, 1],
        orientation=model == "iiwa14-pose",
    )
    q_target = turns(kinematics.joint_count, 1, seed=seed)
    fk = kinematics(q_target)
    target = Target(
        position_m=fk.position_m[0, task.position_axes],
        rotation=fk.rotation[0] if task.orientation else None,
        condition=np.zeros(1, np.float32),
    )
    return kinematics, task, target, q_target


@pytest.mark.parametrize("model", ["iiwa14-pose", "planar3r-position"])
def test_newton_takes_the_numpy_steps(model: str) -> None:
    """DLS steps (every row, and stopping rows at `until`), with locked joints, and the
    bordered steps of a tangent: the compiled Newton ends where `correction.iterate` does,
    to 1e-12, with the error and Jacobian measured there; a NaN row stays in its row."""
    kinematics, task, target, q_target = reached_target(model, seed=16)
    n = kinematics.joint_count
    compiled = Fibre(target, task, kinematics, damping=1e-3)
    through = Fibre(target, task, NumpyStepsKinematics(kinematics), damping=1e-3)
    q = q_target + np.random.default_rng(17).normal(scale=0.05, size=(300, n))
    q[7] = np.nan
    locked = np.random.default_rng(18).random((300, n)) < 0.2
    tangent = unit_tangent(compiled.residual(q)[1])
    cases: list[dict[str, object]] = [
        {"iterations": 4},
        {"iterations": 8, "until": 1e-10},
        {"iterations": 5, "locked": locked},
        {"iterations": 3, "tangent": tangent},
    ]
    for case in cases:
        a = project(compiled, q, **case)  # type: ignore[arg-type]
        b = project(through, q, **case)  # type: ignore[arg-type]
        for x, y in ((a.q_rad, b.q_rad), (a.error, b.error), (a.jacobian, b.jacobian)):
            np.testing.assert_allclose(x, y, rtol=0, atol=1e-12, equal_nan=True)
        assert np.all(np.isnan(a.q_rad[7])) and np.all(np.isfinite(np.delete(a.q_rad, 7, 0)))
        moved = np.linalg.norm(a.error, axis=1) < np.linalg.norm(compiled.residual(q)[0], axis=1)
        assert moved.mean() > 0.9


@pytest.mark.parametrize("model", ["iiwa14-pose", "planar3r-position"])
def test_newton_evaluates_fresh_rows_first_as_if_measured_before(model: str) -> None:
    """Rows marked fresh, whatever their given error and Jacobian, end where the same rows
    measured beforehand end, to the bit, on one thread and on two; rows not fresh are
    read as given (a wrong error given for them moves them elsewhere)."""
    kinematics, task, target, q_target = reached_target(model, seed=36)
    n = kinematics.joint_count
    q = q_target + np.random.default_rng(37).normal(scale=0.05, size=(300, n))
    fresh = np.random.default_rng(38).random(300) < 0.5
    for threads in (1, 2):
        fibre = Fibre(target, task, kinematics, damping=1e-3, threads=threads)
        measured = evaluate(fibre, q)
        given = Projection(
            q, np.where(fresh[:, None], np.inf, measured.error),
            np.where(fresh[:, None, None], np.nan, measured.jacobian),
        )  # fmt: skip
        a = newton(fibre, given, 4, until=1e-10, fresh=fresh)
        b = newton(fibre, measured, 4, until=1e-10)
        for x, y in ((a.q_rad, b.q_rad), (a.error, b.error), (a.jacobian, b.jacobian)):
            np.testing.assert_array_equal(x, y)
        wrong = newton(fibre, Projection(q, measured.error + 0.1, measured.jacobian), 1)
        assert not np.array_equal(wrong.q_rad, b.q_rad)


TILTED_TOOL = [0.6, 0.0, 0.8]  # a tool axis off every joint's, so all joints turn it


def axis_target(kinematics: SerialChainKinematics, q_target: np.ndarray) -> Target:
    """The axis target the configuration (n,) reaches with TILTED_TOOL."""
    fk = kinematics(q_target[None])
    return Target(
        position_m=fk.position_m[0],
        rotation=None,
        condition=np.zeros(1, np.float32),
        axis=fk.rotation[0] @ np.array(TILTED_TOOL),
    )


AXIS_TASK = TaskSpec(name="axis", position_axes=[0, 1, 2], orientation=False, tool_axis=TILTED_TOOL)


def test_axis_residual_is_the_numpy_error_the_angle_and_its_derivative() -> None:
    """The axis task's two rows, compiled, equal `rotations.axis_error` (numpy) to 1e-12
    at configurations over several turns; |e| is the angle between the tool axis and the
    target axis (arccos of their dot product), pi where they are opposite; the Jacobian
    is the derivative of the current value, -de/dq by central differences, on the fibre."""
    kinematics = chain("iiwa14-pose")
    target = axis_target(kinematics, turns(7, 1, seed=30)[0])
    orientation = kernel_orientation(AXIS_TASK, target)
    assert isinstance(orientation, native.AxisTarget)
    q = turns(7, 500, seed=31)
    error, jacobian = native.task_residual(
        kinematics.fixed, kinematics.tip, q, [0, 1, 2], target.position_m, orientation
    )
    expected_error, expected_jacobian = task_error(kinematics(q), target, AXIS_TASK)
    np.testing.assert_allclose(error, expected_error, rtol=0, atol=1e-12)
    np.testing.assert_allclose(jacobian, expected_jacobian, rtol=0, atol=1e-12)
    assert target.axis is not None
    tool = kinematics(q).rotation @ np.array(TILTED_TOOL)  # (B, 3)
    angle = np.arccos(np.clip(tool @ target.axis, -1.0, 1.0))
    np.testing.assert_allclose(np.linalg.norm(error[:, 3:], axis=1), angle, rtol=0, atol=1e-7)
    # On the fibre: from the target configuration, Newton onto it from nearby rows.
    fibre = Fibre(target, AXIS_TASK, kinematics, damping=1e-3)
    near = turns(7, 1, seed=30) + np.random.default_rng(32).normal(scale=0.05, size=(20, 7))
    on = project(fibre, near, iterations=20).q_rad
    assert np.abs(fibre.residual(on)[0]).max() < 1e-12
    step = 1e-6
    for i in range(7):
        dq = np.zeros(7)
        dq[i] = step
        forward, backward = fibre.residual(on + dq)[0], fibre.residual(on - dq)[0]
        derivative = -(forward - backward) / (2 * step)  # e = target - current
        np.testing.assert_allclose(fibre.residual(on)[1][:, :, i], derivative, atol=1e-8)
    # Opposite: the error is pi, not the 0 that the two projections alone would give.
    flipped = Target(target.position_m, None, target.condition, -target.axis)
    on_error = native.task_residual(
        kinematics.fixed, kinematics.tip, on, [0, 1, 2], target.position_m,
        kernel_orientation(AXIS_TASK, flipped),
    )[0]  # fmt: skip
    np.testing.assert_allclose(np.linalg.norm(on_error[:, 3:], axis=1), np.pi, atol=1e-6)


def test_newton_takes_the_numpy_steps_on_the_axis_task() -> None:
    """The compiled Newton on the axis task's rows (DLS, stopping at `until`, a locked
    joint, held exactly) ends where the numpy steps do, to 1e-12, and lands on the fibre.
    (numpy's arctan2 and the C library's differ in the last bit, so the axis rows agree
    to an ulp, not bitwise; each row locks one joint, since with more J can lose rank,
    J J^T + d^2 I then has condition ~1/d^2 = 1e6, and the ulps grow past 1e-12.)"""
    kinematics = chain("iiwa14-pose")
    q_target = turns(7, 1, seed=33)
    target = axis_target(kinematics, q_target[0])
    compiled = Fibre(target, AXIS_TASK, kinematics, damping=1e-3)
    through = Fibre(target, AXIS_TASK, NumpyStepsKinematics(kinematics), damping=1e-3)
    q = q_target + np.random.default_rng(34).normal(scale=0.05, size=(200, 7))
    locked = np.eye(7, dtype=bool)[np.random.default_rng(35).integers(0, 7, 200)]
    cases: list[dict[str, object]] = [
        {"iterations": 4},
        {"iterations": 8, "until": 1e-10},
        {"iterations": 5, "locked": locked},
    ]
    for case in cases:
        a = project(compiled, q, **case)  # type: ignore[arg-type]
        b = project(through, q, **case)  # type: ignore[arg-type]
        for x, y in ((a.q_rad, b.q_rad), (a.error, b.error), (a.jacobian, b.jacobian)):
            np.testing.assert_allclose(x, y, rtol=0, atol=1e-12)
    held = project(compiled, q, iterations=5, locked=locked).q_rad
    np.testing.assert_array_equal(held[locked], q[locked])
    assert np.abs(project(compiled, q, iterations=10).error).max() < 1e-12


def test_smallest_singular_values_equal_lapack() -> None:
    """sigma_min by one-sided Jacobi equals LAPACK's SVD to 1e-12 on the arms' own task
    Jacobians, near-singular ones (a null column, two equal rows) and random shapes; a
    non-finite row is NaN in its own row."""
    rng = np.random.default_rng(21)
    jacobians = [
        chain("iiwa14-pose")(turns(7, 500, seed=22)).jacobian,  # (B, 6, 7) pose rows
        chain("iiwa14-pose")(turns(7, 200, seed=23)).jacobian[:, :3],  # position rows
        chain("planar3r-position")(turns(3, 200, seed=24)).jacobian[:, :2],
        rng.normal(size=(100, 4, 9)),
    ]
    folded = chain("iiwa14-pose")(np.zeros((1, 7))).jacobian  # elbow straight: singular
    twin = rng.normal(size=(1, 5, 6))
    twin[0, 4] = twin[0, 3] * (1 + 1e-9)
    jacobians += [folded, twin]
    for j in jacobians:
        expected = np.linalg.svd(j, compute_uv=False)[:, -1]
        np.testing.assert_allclose(native.smallest_singular_values(j), expected, rtol=0, atol=1e-12)
    broken = jacobians[0][:3].copy()
    broken[1, 2, 3] = np.inf
    sigma = native.smallest_singular_values(broken)
    assert np.isnan(sigma[1]) and np.all(np.isfinite(sigma[[0, 2]]))


def test_least_singular_value_is_the_least_of_every_rows() -> None:
    """The bounded search returns exactly the least of the per-row values: on random sets
    of the iiwa's pose and position Jacobians, with a singular row (the elbow straight),
    rows along a smooth path (many bounds close together) and non-finite rows (skipped;
    inf when none is left)."""
    kinematics = chain("iiwa14-pose")
    rng = np.random.default_rng(27)
    folded = kinematics(np.zeros((1, 7))).jacobian
    path = kinematics(np.linspace(0, 1, 400)[:, None] * rng.uniform(-2, 2, (1, 7))).jacobian
    for trial in range(60):
        j = kinematics(turns(7, int(rng.integers(1, 600)), seed=100 + trial)).jacobian
        j = np.concatenate([j, folded]) if trial % 4 == 0 else j
        j = path if trial % 5 == 0 else j
        j = j[:, :3] if trial % 3 == 0 else j
        j = j.copy()
        if trial % 7 == 0:
            j[0, 0, 0] = np.nan
        expected = float(np.nanmin(native.smallest_singular_values(j), initial=np.inf))
        assert native.least_singular_value(j) == expected
    assert native.least_singular_value(np.full((3, 6, 7), np.nan)) == np.inf


def _turns(count: int, rng: np.random.Generator) -> np.ndarray:
    return Rotation.random(count, random_state=rng).as_matrix()


@pytest.mark.parametrize("model", COLLISION_MODELS)
def test_hull_separation_takes_the_numpy_gjk_steps(model: str) -> None:
    """Pairs of the robot's own hulls (padded as it stores them), turned and placed from
    apart to overlapping, at margins that certify some pairs and give up on others: every
    measured row's compiled GJK bound equals convex.separation_m's to 1e-12, and the rows
    not measured stay -inf."""
    robot = robot_spheres(model)
    hulls = robot.hull_local_m.reshape(-1, *robot.hull_local_m.shape[2:])  # (H, V, 3)
    counts = robot.hull_count.ravel()
    real = np.flatnonzero(counts > 0)
    rng = np.random.default_rng(5)
    size = 400
    a, b = rng.choice(real, size), rng.choice(real, size)
    turn_a, turn_b = _turns(size, rng), _turns(size, rng)
    shift_a = rng.normal(size=(size, 3)) * 0.05
    shift_b = shift_a + rng.normal(size=(size, 3)) * rng.choice([0.02, 0.1, 0.3], (size, 1))
    pad = rng.uniform(0.0, 0.01, size)
    zero = np.zeros(size, dtype=np.int64)
    support_a = hull_support(hulls[:, None], counts[:, None], a, zero, turn_a, shift_a)
    support_b = hull_support(hulls[:, None], counts[:, None], b, zero, turn_b, shift_b)
    x0 = (np.einsum("nij,nj->ni", turn_a, hulls[a, 0]) + shift_a) - (
        np.einsum("nij,nj->ni", turn_b, hulls[b, 0]) + shift_b
    )
    measure = np.sort(rng.choice(size, size - 20, replace=False))
    for margin in (0.0, 0.01, 0.05):
        expected = separation_m(support_a, support_b, x0, pad, margin, measure)
        compiled = native.hull_separation_m(
            hulls, counts, a, turn_a, shift_a, b, turn_b, shift_b, x0, pad, margin, measure
        )
        np.testing.assert_allclose(compiled, expected, rtol=0, atol=1e-12)
        assert np.isneginf(compiled[np.setdiff1d(np.arange(size), measure)]).all()
    assert (compiled[measure] >= 0.05).any() and (compiled[measure] < 0).any()


def test_hull_separation_refuses_hulls_and_rows_out_of_range() -> None:
    hulls, one = np.zeros((2, 4, 3)), np.zeros((1, 3, 3))
    pair = (np.zeros(1, dtype=np.int64), one, np.zeros((1, 3)))
    with pytest.raises(ValueError, match="hull vertex counts must lie in 1 to 4"):
        native.hull_separation_m(
            hulls,
            np.array([4, 0]),
            *pair,
            *pair,
            np.zeros((1, 3)),
            np.zeros(1),
            0.0,
            np.zeros(1, dtype=np.int64),
        )
    with pytest.raises(ValueError, match="hull_b must index 0 to 1"):
        native.hull_separation_m(
            hulls, np.array([4, 4]), *pair, np.array([2]), one, np.zeros((1, 3)),
            np.zeros((1, 3)), np.zeros(1), 0.0, np.zeros(1, dtype=np.int64),
        )  # fmt: skip


@pytest.mark.parametrize("model", COLLISION_MODELS)
def test_refined_self_clearance_at_joint_values_is_the_numpy_passes(model: str) -> None:
    """At configurations whose spheres come within the margin (uniform in the limits, both
    margins the service uses), the compiled refined self-clearance equals robot.py's numpy
    one on the placed bodies (hulls for the sphere pairs within the margin, each
    configuration's deepest pair first) to 1e-12, and so says free exactly where it does;
    some of them are free by the hulls and some are not."""
    served = load_model(REPO_MODELS_DIR / model, threads=1)
    robot = served.robot_spheres
    assert robot is not None
    q = uniform_configurations(served.limits, 3000, seed=3)
    for margin in (0.0, 0.02):
        near = q[robot.self_clearance_at_m(q) < margin]
        expected = robot.refined_self_clearance_m(robot.place(near), np.arange(len(near)), margin)
        compiled = robot.refined_self_clearance_at_m(near, margin)
        np.testing.assert_allclose(compiled, expected, rtol=0, atol=1e-12)
        assert ((compiled >= margin) == (expected >= margin)).all()
        assert (compiled >= margin).any() and (compiled < margin).any()


@pytest.mark.parametrize(
    "periodic", [[True, True, True], [False, True, False, False, True, False, False]]
)
def test_nearest_segment_is_the_numpy_segments_and_brute_force(periodic: list[bool]) -> None:
    """Two paths (an open one and a loop) through joint space, samples beside and far from
    them, periodic joints wrapped: the compiled least segment distance equals the numpy
    segments' (1e-12) with the same candidate point, and with every point a candidate it
    is the least over all segments by brute force."""
    rng = np.random.default_rng(4)
    n = len(periodic)
    mask = np.array(periodic)
    lengths, closed = [40, 25], [False, True]
    walks = [np.cumsum(rng.normal(0, 0.05, (size, n)), axis=0) + rng.uniform(-3, 3, n)
             for size in lengths]  # fmt: skip
    points = np.where(mask, np.mod(np.concatenate(walks) + np.pi, 2 * np.pi) - np.pi,
                      np.concatenate(walks))  # fmt: skip
    first = np.array([0, lengths[0]])
    last = first + np.array(lengths) - 1
    before, after = np.arange(len(points)) - 1, np.arange(len(points)) + 1
    before[first] = np.where(closed, last, first)
    after[last] = np.where(closed, first, last)
    q = points[rng.integers(0, len(points), 30)] + rng.normal(0, 0.02, (30, n))
    q = np.concatenate([q, rng.uniform(-3, 3, (10, n))])  # far from both
    nearest = np.argsort(rng.uniform(size=(len(q), len(points))), axis=1)[:, :4]
    distance, point = native.nearest_segment(q, points, before, after, nearest, mask)
    numpy_distance, numpy_point = numpy_nearest_segment(q, points, before, after, nearest, mask)
    np.testing.assert_allclose(distance, numpy_distance, rtol=0, atol=1e-12)
    assert point.tolist() == numpy_point.tolist()
    every = np.tile(np.arange(len(points)), (len(q), 1))
    least, _ = native.nearest_segment(q, points, before, after, every, mask)
    a, b = points[:-1], points[1:]
    segments = [(i, i + 1) for i in range(len(points) - 1) if i + 1 not in first]
    segments.append((last[1], first[1]))  # the loop's closing segment
    brute = np.full(len(q), np.inf)
    for i, j in segments:
        a, b = np.broadcast_to(points[i], q.shape), np.broadcast_to(points[j], q.shape)
        d = numpy_segment_distance(q, a[:, None], b[:, None], mask)[:, 0]
        brute = np.minimum(brute, d)
    np.testing.assert_allclose(least, brute, rtol=0, atol=1e-12)
    assert distance.min() >= 0 and (distance >= least - 1e-15).all()
    # A -1 candidate is none: the others decide, and a row with none is +inf and -1.
    fewer = nearest.copy()
    fewer[:, 2:] = -1
    fewer[0] = -1
    partial, which = native.nearest_segment(q, points, before, after, fewer, mask)
    expected, expected_point = native.nearest_segment(
        q, points, before, after, nearest[:, :2], mask
    )
    np.testing.assert_array_equal(partial[1:], expected[1:])
    assert which[1:].tolist() == expected_point[1:].tolist()
    assert partial[0] == np.inf and which[0] == -1


def test_nearest_segment_refuses_indices_out_of_range() -> None:
    points = np.zeros((3, 2))
    ends = np.array([0, 1, 2])
    for wrong in (3, -2):
        with pytest.raises(ValueError, match="nearest must index the 3 points"):
            native.nearest_segment(
                np.zeros((1, 2)), points, ends, ends, np.array([[wrong]]), np.zeros(2, bool)
            )
    with pytest.raises(ValueError, match="before and after must index the 3 points"):
        native.nearest_segment(
            np.zeros((1, 2)), points, np.array([0, 1, 5]), ends, np.array([[0]]), np.zeros(2, bool)
        )


@pytest.mark.parametrize("periodic", [[True, False, True], [False, False, False]])
def test_nearest_in_group_is_the_brute_force_nearest_of_the_querys_group(
    periodic: list[bool],
) -> None:
    rng = np.random.default_rng(5)
    mask = np.array(periodic)
    point_group = np.sort(rng.integers(0, 6, 3000))
    points = rng.uniform(-3.0, 3.0, (3000, 3))
    queries = rng.uniform(-3.0, 3.0, (200, 3))
    query_group = rng.integers(0, 8, 200)  # groups 6 and 7 have no point
    nearest = native.nearest_in_group(points, point_group, queries, query_group, mask)
    for i, group in enumerate(query_group):
        mine = np.flatnonzero(point_group == group)
        if not len(mine):
            assert nearest[i] == -1
            continue
        assert nearest[i] == mine[np.argmin(joint_distance(queries[i], points[mine], mask))]
    assert (nearest >= 0).sum() > 100


def test_nearest_in_group_refuses_unsorted_groups() -> None:
    with pytest.raises(ValueError, match="sorted ascending"):
        native.nearest_in_group(
            np.zeros((2, 3)), np.array([1, 0]), np.zeros((1, 3)), np.array([0]), np.zeros(3, bool)
        )


@pytest.mark.parametrize("n", [3, 7])
def test_the_traces_hermite_guesses_and_tangent_signs_are_numpys_to_the_bit(n: int) -> None:
    """Steps like the trace's (0.1 rad chords anywhere on three turns), unit end tangents
    of either sign, one row in seven with a NaN tangent: `along` and `hermite` give the
    numpy steps' values bitwise, so the trace's answers did not move."""
    rng = np.random.default_rng(8)
    count = 4000
    p0 = rng.uniform(-3 * np.pi, 3 * np.pi, (count, n))
    p1 = p0 + rng.normal(0.0, 0.1, (count, n))
    t0, t1 = (rng.normal(size=(count, n)) for _ in range(2))
    t0, t1 = (t / np.linalg.norm(t, axis=1, keepdims=True) for t in (t0, t1))
    s = rng.uniform(0.0, 1.0, count)
    for compiled, reference in zip(
        native.hermite(p0, t0, p1, t1, s), numpy_hermite(p0, t0, p1, t1, s), strict=True
    ):
        np.testing.assert_array_equal(compiled, reference)
    broken = t0.copy()
    broken[::7, 1] = np.nan
    for tangent in (t0, broken):
        np.testing.assert_array_equal(native.along(tangent, p1 - p0), numpy_along(tangent, p1 - p0))
    assert np.all(np.einsum("kn,kn->k", native.along(broken, p1 - p0), p1 - p0) >= 0)


def test_the_dense_points_are_settled_as_the_numpy_steps_settle_them() -> None:
    """Points over several turns, some carried far from where they were placed, limited
    and periodic joints, fixed and excluded rows: the same windowed and wrapped values and
    the same inside flags as numpy's mod, limits and wrap, bitwise."""
    rng = np.random.default_rng(9)
    count, n = 3000, 7
    q = rng.uniform(-8.0, 8.0, (count, n))
    placed = q + rng.normal(0.0, 0.03, (count, n))
    low = np.where(np.arange(n) % 2 == 0, -np.pi, -2.0)
    lower, upper = np.full(n, -2.5), np.full(n, 2.5)
    periodic = np.arange(n) % 3 == 0
    fixed_rows, excluded = np.array([3, 10, 11]), np.array([5, 10])
    fixed = rng.uniform(-2.0, 2.0, (3, n))
    args = (q, placed, low, lower, upper, periodic, 0.05, fixed_rows, fixed, excluded)
    settled, inside = native.settle_dense(*args)
    expected_q, expected_inside = numpy_settle_dense(*args)
    np.testing.assert_array_equal(settled, expected_q)
    np.testing.assert_array_equal(inside, expected_inside)
    assert 0 < inside.sum() < count and not inside[10]
    np.testing.assert_array_equal(settled[fixed_rows[:2]][:, ~periodic], fixed[:2][:, ~periodic])


def test_the_steps_refined_near_the_limits_are_the_numpy_slab_tests() -> None:
    """Trace steps anywhere on three turns (some of zero length, some NaN), limited and
    periodic joints: the compiled choice of the steps to split is the numpy window, limits
    and slab test's, step for step; both pick steps and leave others."""
    rng = np.random.default_rng(11)
    count, n = 20000, 7
    start = rng.uniform(-3 * np.pi, 3 * np.pi, (count, n))
    delta = rng.normal(0.0, 0.3, (count, n))
    delta[::50] = 0.0
    start[::97, 2] = np.nan
    low = np.where(np.arange(n) % 2 == 0, -np.pi, -2.0)
    lower, upper = np.full(n, -1.5), np.full(n, 1.5)
    periodic = np.arange(n) == 3
    args = (start, delta, low, lower, upper, periodic)
    split = native.steps_near_limits(*args)
    np.testing.assert_array_equal(split, numpy_steps_near_limits(*args))
    assert 0 < split.sum() < count


@pytest.mark.parametrize("n", [2, 3, 7])
def test_nearest_points_are_the_brute_force_nearest_in_order(n: int) -> None:
    """Random walks as paths (some joints periodic, wrapped), queries beside them and far
    off, fewer points than asked for: each query's k nearest points are the brute-force
    joint-metric order (the lower row first among equally near), -1 past the last point;
    within a reach, the same with those beyond it -1."""
    rng = np.random.default_rng(12 + n)
    for _ in range(40):
        periodic = rng.uniform(size=n) < 0.4
        size, count = int(rng.integers(1, 600)), int(rng.integers(1, 150))
        walk = np.cumsum(rng.normal(0.0, 0.05, (size, n)), axis=0) + rng.uniform(-3, 3, n)
        points = np.where(periodic, np.mod(walk + np.pi, 2 * np.pi) - np.pi, walk)
        queries = points[rng.integers(0, size, count)]
        queries = queries + rng.normal(0.0, float(rng.choice([0.01, 0.5])), (count, n))
        nearest = native.nearest_points(points, queries, periodic, 4)
        distance = np.stack([joint_distance(q, points, periodic) for q in queries])
        expected = np.argsort(distance, axis=1, kind="stable")[:, :4]
        np.testing.assert_array_equal(nearest[:, : min(4, size)], expected)
        assert np.all(nearest[:, size:] == -1)
        # Within a reach: the same nearest, those beyond it left out (-1).
        reach = 0.1
        near = native.nearest_points(points, queries, periodic, 4, reach)
        within = np.take_along_axis(distance, expected, axis=1) <= reach
        np.testing.assert_array_equal(near[:, : min(4, size)], np.where(within, expected, -1))


@pytest.mark.parametrize("periodic", [False, True])
def test_nearest_of_sets_and_links_within_are_the_brute_force_ones(periodic: bool) -> None:
    """Nodes in components (sets; -1: a lone node, in none), a KD-tree box periodic or not:
    each node's nearest node of every set it is not in, within the radius, is the
    brute-force one in the box metric (the lower row among equally near), listed by set
    then node whatever block of nodes is tabled at once, and every node's links within
    the radius are every other node nearer than it, in order."""
    rng = np.random.default_rng(13)
    count, n, sets, radius = 300, 4, 7, 1.2
    points = rng.uniform(0.0, 4.0, (count, n))
    set_of = rng.integers(-1, sets, count)
    box = np.full(n, 4.0 if periodic else np.inf)

    def metric(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        d = a - b
        if periodic:
            d = np.where(d > 2.0, d - 4.0, np.where(d < -2.0, d + 4.0, d))
        return np.sqrt(np.sum(d * d, axis=-1))

    nearest, x_of, length = native.nearest_of_sets(points, box, set_of, sets, radius, threads=2)
    expected: list[tuple[int, int, int, float]] = []  # (set, x, its nearest, distance)
    for m in range(sets):
        mine = np.flatnonzero(set_of == m)
        for x in range(count):
            to_mine = metric(points[x], points[mine]) if len(mine) else np.zeros(0)
            if m != set_of[x] and len(mine) and to_mine.min() < radius:
                expected.append((m, x, int(mine[np.argmin(to_mine)]), float(to_mine.min())))
    assert nearest.tolist() == [e[2] for e in expected]  # in order of set, then node
    assert x_of.tolist() == [e[1] for e in expected]
    np.testing.assert_allclose(length, [e[3] for e in expected], rtol=0, atol=1e-12)
    # A block of a few rows at a time gives the same links.
    blocks = native.SETS_BLOCK_ROWS
    try:
        native.SETS_BLOCK_ROWS = 7
        again = native.nearest_of_sets(points, box, set_of, sets, radius, threads=2)
    finally:
        native.SETS_BLOCK_ROWS = blocks
    for mine_, theirs in zip(again, (nearest, x_of, length), strict=True):
        np.testing.assert_array_equal(mine_, theirs)
    rows = np.array([0, 5, 17])
    i, y, length = native.links_within(points, box, rows, radius)
    for k, row in enumerate(rows):
        to_all = metric(points[row], points)
        near = np.flatnonzero((to_all < radius) & (np.arange(count) != row))
        np.testing.assert_array_equal(y[i == k], near)
        np.testing.assert_allclose(length[i == k], to_all[near], atol=1e-12)
    assert np.all(np.diff(i) >= 0)


def test_merged_labels_are_scipys_components_numbered_by_lowest_node() -> None:
    """Parts of nodes merged along random edges between parts: the same partition as
    scipy's connected components of the parts' graph, numbered 0, 1, ... in the order of
    each part's lowest node (what connected_components gives a graph of the nodes)."""
    rng = np.random.default_rng(14)
    for _ in range(50):
        parts = int(rng.integers(1, 60))
        labels = rng.integers(0, parts, int(rng.integers(1, 200)))
        edges = int(rng.integers(0, 40))
        a, b = rng.integers(0, parts, edges), rng.integers(0, parts, edges)
        graph = coo_matrix((np.ones(edges), (a, b)), shape=(parts, parts))
        component = connected_components(graph, directed=False)[1][labels]
        _, first = np.unique(component, return_index=True)
        rank = np.empty(len(first), dtype=np.int64)
        rank[np.argsort(first)] = np.arange(len(first))
        expected = rank[np.unique(component, return_inverse=True)[1]]
        np.testing.assert_array_equal(native.merge_labels(labels, a, b), expected)
