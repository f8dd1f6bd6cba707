"""correction: a DLS step follows its closed form and reduces the error; a converged sample
takes no further step while the others take every one; bad samples are fenced; on a
serial chain the compiled loop takes the numpy loop's steps bitwise; a correction that
leaves no sample within tolerance goes further for the samples near the target (the arm
at full reach), and only then."""

import numpy as np
import pytest

from service.manifest import REPO_MODELS_DIR, TaskSpec
from service.models.chain import SerialChainKinematics
from service.models.registry import ServedModel, load_model
from service.pipeline.correction import (
    CHUNK_ROWS,
    CONVERGED_ERROR,
    EXTRA_STEPS,
    NEAR_TOLERANCES,
    correct,
    correct_further,
    dls_step,
)
from service.pipeline.joint_space import JointLimits
from service.pipeline.targets import Target
from service.pipeline.types import KinematicsResult, Tolerance
from tests.support.numpy_kernels import NumpyStepsKinematics
from training.evaluate.references.planar3r import planar3r_jacobian, planar3r_position

POSITION_2D = TaskSpec(name="position", position_axes=[0, 1], orientation=False)
LIMITS = JointLimits(np.full(3, -np.pi), np.full(3, np.pi), np.array([True, True, True]))


def closed_form_kinematics(q_rad: np.ndarray) -> KinematicsResult:
    """Planar 3R FK and Jacobian from the closed form, in the pipeline's container."""
    batch = q_rad.shape[0]
    position = np.zeros((batch, 3))
    position[:, :2] = planar3r_position(q_rad)
    jacobian = np.zeros((batch, 6, 3))
    jacobian[:, :2] = planar3r_jacobian(q_rad)
    jacobian[:, 5] = 1.0
    return KinematicsResult(
        position_m=position, rotation=np.tile(np.eye(3), (batch, 1, 1)), jacobian=jacobian
    )


def target_at(position: np.ndarray) -> Target:
    return Target(position_m=position, rotation=None, condition=np.zeros(2, np.float32))


def test_dls_step_equals_the_damped_pseudo_inverse() -> None:
    rng = np.random.default_rng(0)
    jacobian = rng.normal(size=(5, 2, 3))
    error = rng.normal(size=(5, 2))
    damping = 0.1
    dq = dls_step(jacobian, error, damping)
    for J, e, step in zip(jacobian, error, dq, strict=True):
        expected = J.T @ np.linalg.inv(J @ J.T + damping**2 * np.eye(2)) @ e
        np.testing.assert_allclose(step, expected, rtol=1e-12)
    # Vanishing damping on a square, well-conditioned Jacobian: the Newton step J^-1 e.
    square = rng.normal(size=(4, 3, 3)) + 3 * np.eye(3)
    np.testing.assert_allclose(
        dls_step(square, error[:4, :1].repeat(3, 1), 1e-9),
        np.linalg.solve(square, error[:4, :1].repeat(3, 1)[..., None])[..., 0],
        rtol=1e-6,
    )


def test_one_dls_step_reduces_the_task_error() -> None:
    rng = np.random.default_rng(1)
    q_true = rng.uniform(-np.pi, np.pi, (200, 3))
    target = planar3r_position(q_true)
    q = q_true + rng.normal(0, 0.05, q_true.shape)
    error = target - planar3r_position(q)
    q_next = q + dls_step(planar3r_jacobian(q), error, 1e-3)
    error_next = target - planar3r_position(q_next)
    assert np.all(np.linalg.norm(error_next, axis=1) < np.linalg.norm(error, axis=1))


def test_correct_converges_with_the_exported_kinematics(planar3r: ServedModel) -> None:
    rng = np.random.default_rng(2)
    q_true = rng.uniform(-np.pi, np.pi, (1, 3))
    target = planar3r_position(q_true)[0]
    q = q_true + rng.normal(0, 0.01, (100, 3))  # raw flow samples are mm, i.e. mrad, off
    result = correct(q, target_at(target), POSITION_2D, planar3r.kinematics, 3, 1e-3, LIMITS)
    closed_form_error = np.linalg.norm(planar3r_position(result.q_rad) - target, axis=1)
    assert closed_form_error.max() < 1e-9
    np.testing.assert_allclose(result.position_error_m, closed_form_error, atol=1e-12)
    assert np.all(np.abs(result.q_rad) <= np.pi)


def test_a_converged_sample_stops_and_the_others_take_every_step() -> None:
    q_on = np.array([0.3, 0.4, -0.2])
    target = planar3r_position(q_on[None])[0]
    q_off = q_on + np.array([0.2, -0.1, 0.1])  # far enough to need every step
    result = correct(
        np.stack([q_on, q_off]), target_at(target), POSITION_2D, closed_form_kinematics, 3,
        1e-3, LIMITS,
    )  # fmt: skip
    # On the fibre already (|e| ~ 1e-16 < CONVERGED_ERROR): not moved at all.
    np.testing.assert_array_equal(result.q_rad[0], q_on)
    # Off it: the three closed-form DLS steps, one after another (above CONVERGED_ERROR
    # before each, so none is skipped).
    q = q_off
    for _ in range(3):
        error = target - planar3r_position(q[None])
        assert np.linalg.norm(error) > CONVERGED_ERROR
        q = q + dls_step(planar3r_jacobian(q[None]), error, 1e-3)[0]
    np.testing.assert_allclose(result.q_rad[1], q, atol=1e-14)


def test_non_finite_samples_get_infinite_error_and_leave_the_others_alone() -> None:
    q_true = np.array([[0.3, 0.4, -0.2]])
    target = planar3r_position(q_true)[0]
    q = np.array([[0.31, 0.41, -0.21], [np.nan, 0.0, 0.0], [np.inf, 1.0, 1.0]])
    result = correct(q, target_at(target), POSITION_2D, closed_form_kinematics, 4, 1e-3, LIMITS)
    assert result.position_error_m[0] < 1e-10
    assert np.all(np.isinf(result.position_error_m[1:]))
    assert np.all(np.isnan(result.q_rad[1:]))


def test_all_non_finite_samples_skip_the_kinematics(planar3r: ServedModel) -> None:
    q = np.full((4, 3), np.nan)
    target = target_at(np.array([0.5, 0.0]))
    result = correct(q, target, POSITION_2D, planar3r.kinematics, 3, 1e-3, LIMITS)
    assert np.all(np.isinf(result.position_error_m)) and np.all(np.isnan(result.q_rad))


MICROMETRE = Tolerance(position_m=1e-6, orientation_rad=1e-6)


class CountingKinematics:
    """The planar closed form, counting the configurations it is asked for."""

    def __init__(self) -> None:
        self.rows = 0

    def __call__(self, q_rad: np.ndarray) -> KinematicsResult:
        self.rows += len(q_rad)
        return closed_form_kinematics(q_rad)


def test_at_full_reach_a_correction_with_none_within_tolerance_goes_further() -> None:
    # The arm stretched out (q2 = q3 = 0): a fold of the task map, where the damping slows
    # DLS. Three steps leave every sample off by more than the tolerance.
    rng = np.random.default_rng(3)
    q_on = np.array([0.4, 0.0, 0.0])
    target = planar3r_position(q_on[None])[0]
    q = q_on + rng.normal(0, 0.05, (50, 3))
    q[-1] = q_on + np.array([0.0, 1.5, -1.0])  # far off: outside the near radius
    served = correct(q, target_at(target), POSITION_2D, closed_form_kinematics, 3, 1e-3, LIMITS)
    assert not MICROMETRE.within(served.position_error_m, served.orientation_error_rad).any()
    assert served.position_error_m[-1] > NEAR_TOLERANCES * MICROMETRE.position_m
    further = correct_further(
        served, MICROMETRE, target_at(target), POSITION_2D, closed_form_kinematics, 1e-3, LIMITS
    )
    within = MICROMETRE.within(further.position_error_m, further.orientation_error_rad)
    assert within.sum() >= 10
    # Against the closed form: the errors are the configurations' own.
    closed_form_error = np.linalg.norm(planar3r_position(further.q_rad) - target, axis=1)
    np.testing.assert_allclose(further.position_error_m, closed_form_error, atol=1e-12)
    # The samples near the target took EXTRA_STEPS more steps of the same DLS from where
    # the served steps left them; the others (the far one among them) stayed there.
    near = served.position_error_m <= NEAR_TOLERANCES * MICROMETRE.position_m
    assert 10 <= near.sum() < len(q) and not near[-1]
    again = correct(
        served.q_rad[near], target_at(target), POSITION_2D, closed_form_kinematics, EXTRA_STEPS,
        1e-3, LIMITS,
    )  # fmt: skip
    np.testing.assert_array_equal(further.q_rad[near], again.q_rad)
    np.testing.assert_array_equal(further.q_rad[~near], served.q_rad[~near])
    np.testing.assert_array_equal(further.position_error_m[~near], served.position_error_m[~near])


def test_a_correction_with_a_sample_within_tolerance_is_the_answer_as_it_is() -> None:
    q_on = np.array([0.3, 0.4, -0.2])
    target = planar3r_position(q_on[None])[0]
    q = np.stack([q_on + 1e-3, q_on + np.array([0.2, -0.1, 0.1])])
    served = correct(q, target_at(target), POSITION_2D, closed_form_kinematics, 3, 1e-3, LIMITS)
    within = MICROMETRE.within(served.position_error_m, served.orientation_error_rad)
    assert within[0] and not within[1]
    kinematics = CountingKinematics()
    further = correct_further(
        served, MICROMETRE, target_at(target), POSITION_2D, kinematics, 1e-3, LIMITS
    )
    assert further is served and kinematics.rows == 0


def test_a_target_out_of_reach_costs_no_further_step() -> None:
    target = np.array([3.01, 0.0])  # 1 cm beyond the planar arm's reach of 3 m
    q = np.random.default_rng(4).normal(0, 0.05, (20, 3))
    served = correct(q, target_at(target), POSITION_2D, closed_form_kinematics, 3, 1e-3, LIMITS)
    assert served.position_error_m.min() > NEAR_TOLERANCES * MICROMETRE.position_m
    kinematics = CountingKinematics()
    further = correct_further(
        served, MICROMETRE, target_at(target), POSITION_2D, kinematics, 1e-3, LIMITS
    )
    assert further is served and kinematics.rows == 0


def test_a_non_finite_row_gets_a_nan_step_and_leaves_the_others_exact() -> None:
    rng = np.random.default_rng(1)
    jacobian = rng.normal(size=(5, 2, 3))
    error = rng.normal(size=(5, 2))
    clean = dls_step(jacobian, error, 0.1)
    jacobian[1, 0, 2] = np.nan
    error[2, 1] = np.inf
    jacobian[4, 0, 0], error[4, 0] = np.inf, -np.inf  # infinities of both signs in one row
    dq = dls_step(jacobian, error, 0.1)
    assert np.isnan(dq[[1, 2, 4]]).all()
    np.testing.assert_array_equal(dq[[0, 3]], clean[[0, 3]])
    # Every row finite: the same steps as row by row.
    for row in (0, 3):
        np.testing.assert_array_equal(dls_step(jacobian[[row]], error[[row]], 0.1)[0], clean[row])


def test_a_singular_system_falls_back_to_the_pseudo_inverse() -> None:
    # Zero damping at a singularity: J J^T is singular (rank 1), np.linalg.solve fails;
    # the step is then the minimum-norm least-squares one, J^+ e.
    jacobian = np.array([[[1.0, 1.0, 1.0], [2.0, 2.0, 2.0]], [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    error = np.array([[0.3, -0.2], [0.5, 0.25]])
    dq = dls_step(jacobian, error, damping=0.0)
    for J, e, step in zip(jacobian, error, dq, strict=True):
        np.testing.assert_allclose(step, np.linalg.pinv(J) @ e, atol=1e-12)


def test_a_nan_from_the_kinematics_rejects_only_its_own_sample() -> None:
    def faulty_kinematics(q_rad: np.ndarray) -> KinematicsResult:
        fk = closed_form_kinematics(q_rad)
        broken = q_rad[:, 0] > 1.0  # this network fails for a part of joint space
        fk.position_m[broken] = np.nan
        fk.jacobian[broken] = np.nan
        return fk

    q = np.array([[0.1, 1.0, 1.0], [2.0, 1.0, 1.0], [-0.4, 1.2, 0.9]])
    target = target_at(planar3r_position(q[:1])[0] + 0.01)
    correction = correct(q, target, POSITION_2D, faulty_kinematics, 3, 1e-3, LIMITS)
    assert np.isnan(correction.position_error_m[1])
    assert np.all(np.isfinite(correction.position_error_m[[0, 2]]))
    healthy = correct(q[[0, 2]], target, POSITION_2D, closed_form_kinematics, 3, 1e-3, LIMITS)
    np.testing.assert_array_equal(correction.q_rad[[0, 2]], healthy.q_rad)


@pytest.mark.parametrize("model_id", ["iiwa14-pose", "iiwa14-position", "planar3r-position"])
def test_the_compiled_correction_is_the_numpy_steps_bitwise(model_id: str) -> None:
    """Where the kinematics is a serial chain, every DLS step of a chunk of rows runs in one
    compiled call (`native.newton`); it ends where `iterate`'s numpy loop does over the same
    compiled kernels (the chain behind a plain callable), bitwise: every row, its error
    and Jacobian, rows already converged, a non-finite sample, and rows over several
    chunks."""
    model = load_model(REPO_MODELS_DIR / model_id, threads=1)
    manifest = model.manifest
    task, limits = manifest.task, model.limits
    chain = model.kinematics
    assert isinstance(chain, SerialChainKinematics)
    rng = np.random.default_rng(5)
    q_target = rng.uniform(limits.lower_rad, limits.upper_rad)
    fk = chain(q_target[None])
    target = Target(
        position_m=fk.position_m[0, task.position_axes],
        rotation=fk.rotation[0] if task.orientation else None,
        condition=np.zeros(1, np.float32),
    )
    q = q_target + rng.normal(0, 0.05, (CHUNK_ROWS + 300, limits.count))
    q[3] = q_target  # on the fibre already: converged before the first step
    q[11, 0] = np.nan
    steps, damping = manifest.defaults.correction_steps, manifest.defaults.damping
    compiled = correct(q, target, task, chain, steps, damping, limits)
    through = correct(q, target, task, NumpyStepsKinematics(chain), steps, damping, limits)
    for field in ("q_rad", "position_error_m", "orientation_error_rad", "jacobian"):
        np.testing.assert_array_equal(getattr(compiled, field), getattr(through, field))
    assert compiled.position_error_m[3] < 1e-12 and np.isinf(compiled.position_error_m[11])
    assert np.median(compiled.position_error_m) < 1e-9
