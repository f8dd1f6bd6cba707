"""kinematics.onnx (planar 3R): FK equals the closed form, Jacobian equals finite differences;
every session is opened with the threads asked and with workers that do not spin; the
flow network (float32 and int8) gives the same velocities on one thread and on two.

The session is opened on the bundled model's kinematics.onnx directly: the registry serves
its chain.json kernel (tests/service/models/test_chain.py), and kinematics.onnx is what
that kernel is checked against at load and what models without chain.json are served by.
"""

import numpy as np
import pytest

from service.manifest import FLOW_FILE, FLOW_INT8_FILE, KINEMATICS_FILE
from service.models.sessions import OnnxKinematics, OnnxVelocityField, open_session
from tests.support.app import PLANAR3R_DIR
from training.evaluate.references.planar3r import planar3r_jacobian, planar3r_position


@pytest.fixture(scope="module")
def kinematics() -> OnnxKinematics:
    return OnnxKinematics(open_session(PLANAR3R_DIR / KINEMATICS_FILE, threads=1))


def test_forward_kinematics_matches_the_closed_form(kinematics: OnnxKinematics) -> None:
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, (500, 3))
    fk = kinematics(q)
    np.testing.assert_allclose(fk.position_m[:, :2], planar3r_position(q), atol=1e-12)
    np.testing.assert_allclose(fk.position_m[:, 2], 0.0, atol=1e-12)
    angle = q.sum(axis=1)
    np.testing.assert_allclose(fk.rotation[:, 0, 0], np.cos(angle), atol=1e-12)
    np.testing.assert_allclose(fk.rotation[:, 1, 0], np.sin(angle), atol=1e-12)


def test_jacobian_matches_central_finite_differences(kinematics: OnnxKinematics) -> None:
    q = np.random.default_rng(1).uniform(-np.pi, np.pi, (50, 3))
    jacobian = kinematics(q).jacobian  # (B, 6, 3)
    step = 1e-6
    for j in range(3):
        dq = np.zeros(3)
        dq[j] = step
        forward = kinematics(q + dq).position_m
        backward = kinematics(q - dq).position_m
        np.testing.assert_allclose(jacobian[:, :3, j], (forward - backward) / (2 * step), atol=1e-8)
    np.testing.assert_allclose(jacobian[:, :2], planar3r_jacobian(q), atol=1e-12)
    np.testing.assert_allclose(jacobian[:, 5], 1.0, atol=1e-12)  # every joint turns about z


def test_batch_size_is_dynamic(kinematics: OnnxKinematics) -> None:
    for batch in (1, 7, 2048):
        assert kinematics(np.zeros((batch, 3))).jacobian.shape == (batch, 6, 3)


def test_sessions_take_the_threads_asked_and_do_not_spin() -> None:
    session = open_session(PLANAR3R_DIR / KINEMATICS_FILE, threads=2)
    options = session.get_session_options()
    assert (options.intra_op_num_threads, options.inter_op_num_threads) == (2, 1)
    for pool in ("intra_op", "inter_op"):
        assert options.get_session_config_entry(f"session.{pool}.allow_spinning") == "0"


@pytest.mark.parametrize("flow_file", [FLOW_FILE, FLOW_INT8_FILE])
def test_the_flow_gives_the_same_velocities_on_one_thread_and_on_two(flow_file: str) -> None:
    """The service runs the flow on the process's cores (Settings): a request's answer must
    not depend on how many, or the benchmark's figures would not be the served ones."""
    rng = np.random.default_rng(2)
    batch = 1000
    inputs = {
        "q_t": rng.standard_normal((batch, 3)).astype(np.float32),
        "t": rng.uniform(0, 1, (batch, 1)).astype(np.float32),
        "condition": rng.standard_normal((batch, 2)).astype(np.float32),
    }
    one, two = (
        OnnxVelocityField(open_session(PLANAR3R_DIR / flow_file, threads=threads))
        for threads in (1, 2)
    )
    np.testing.assert_array_equal(one(**inputs), two(**inputs))
