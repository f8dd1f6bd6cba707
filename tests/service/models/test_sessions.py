"""kinematics.onnx (planar 3R): FK equals the closed form, Jacobian equals finite differences;
every session is opened with the threads asked, its workers spinning only while a call runs
(the process takes no CPU once the call returns); every
bundled flow network gives the same velocities on one thread and on two, and a call runs
on every thread only when it is large and no other runs.

The session is opened on the bundled model's kinematics.onnx directly: the registry serves
its chain.json kernel (tests/service/models/test_chain.py), and kinematics.onnx is what
that kernel is checked against at load and what models without chain.json are served by.
"""

import json
import time

import numpy as np
import pytest

from service.manifest import (
    FLOW_FILES,
    FLOW_INT8_FILE,
    KINEMATICS_FILE,
    MANIFEST_FILE,
    REPO_MODELS_DIR,
)
from service.models.registry import load_model
from service.models.sessions import (
    PARALLEL_MIN_ROWS,
    OnnxKinematics,
    OnnxVelocityField,
    open_session,
)
from tests.support.app import PLANAR3R_DIR
from tests.support.bundled import bundled_model_ids
from training.evaluate.references.planar3r import planar3r_jacobian, planar3r_position

IIWA14_POSE_DIR = REPO_MODELS_DIR / "iiwa14-pose"


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


def test_sessions_take_the_threads_asked_and_spin_only_within_a_call() -> None:
    session = open_session(PLANAR3R_DIR / KINEMATICS_FILE, threads=2)
    options = session.get_session_options()
    assert (options.intra_op_num_threads, options.inter_op_num_threads) == (2, 1)
    assert options.get_session_config_entry("session.intra_op.allow_spinning") == "1"
    assert options.get_session_config_entry("session.force_spinning_stop") == "1"
    assert options.get_session_config_entry("session.inter_op.allow_spinning") == "0"


def test_an_idle_process_spins_no_worker_after_a_parallel_call() -> None:
    """After a call on two threads returns, its worker sleeps: the process uses (almost) no
    CPU while it waits. A worker left spinning takes tens of milliseconds of CPU there."""
    flow = OnnxVelocityField.open(IIWA14_POSE_DIR / FLOW_INT8_FILE, threads=2, serial=False)
    rows = 2 * PARALLEL_MIN_ROWS
    q_t, t = np.zeros((rows, 7), np.float32), np.zeros((rows, 1), np.float32)
    condition = np.zeros((rows, 9), np.float32)
    for _ in range(3):
        flow(q_t, t, condition)
        cpu_s = time.process_time()
        time.sleep(0.2)
        assert time.process_time() - cpu_s < 0.01


def _bundled_flows() -> list[tuple[str, str]]:
    """(model id, flow file) for every flow network a bundled manifest lists."""
    flows = []
    for model_id in bundled_model_ids():
        files = json.loads((REPO_MODELS_DIR / model_id / MANIFEST_FILE).read_text())["files"]
        flows += [(model_id, name) for name in FLOW_FILES.values() if name in files]
    return flows


@pytest.mark.parametrize(("model_id", "flow_file"), _bundled_flows())
def test_the_flow_gives_the_same_velocities_on_one_thread_and_on_two(
    model_id: str, flow_file: str
) -> None:
    """The service runs a large flow call on the process's cores and a small one, or one
    made while another runs, on one thread (`OnnxVelocityField.session_for`): a request's
    answer must depend on neither, or it would change with the load and the benchmark's
    figures would not be the served ones."""
    path = REPO_MODELS_DIR / model_id / flow_file
    one, two = (open_session(path, threads=threads) for threads in (1, 2))
    n, c = (one.get_inputs()[k].shape[1] for k in (0, 2))
    rng = np.random.default_rng(2)
    for batch in (100, PARALLEL_MIN_ROWS, 1000):
        inputs = {
            "q_t": rng.standard_normal((batch, n)).astype(np.float32),
            "t": rng.uniform(0, 1, (batch, 1)).astype(np.float32),
            "condition": rng.standard_normal((batch, c)).astype(np.float32),
        }
        (v_one,), (v_two,) = (s.run(["velocity"], inputs) for s in (one, two))
        np.testing.assert_array_equal(v_one, v_two)


def test_a_flow_call_runs_on_every_thread_only_when_large_and_alone() -> None:
    path = PLANAR3R_DIR / FLOW_INT8_FILE
    flow = OnnxVelocityField.open(path, threads=2)
    parallel, serial = (flow.session_for(PARALLEL_MIN_ROWS, 0), flow.session_for(1, 0))
    assert parallel.get_session_options().intra_op_num_threads == 2
    assert serial.get_session_options().intra_op_num_threads == 1
    assert flow.session_for(PARALLEL_MIN_ROWS - 1, 0) is serial
    assert flow.session_for(10 * PARALLEL_MIN_ROWS, 1) is serial  # another call runs
    alone = OnnxVelocityField.open(path, threads=1)
    assert alone.session_for(10 * PARALLEL_MIN_ROWS, 0) is alone.session_for(1, 0)


def test_the_registry_opens_a_one_thread_session_only_beside_the_served_network() -> None:
    """Each one-thread session holds its own weights: only the network a request's default
    sampler evaluates gets one; the others run every call on their parallel session (with
    the int8 networks on onnxruntime too, not on the compiled layers)."""
    model = load_model(PLANAR3R_DIR, threads=2, compiled_int8=False)
    for name, network in model.networks.items():
        assert isinstance(network, OnnxVelocityField)
        small = network.session_for(1, 0)
        served = name == model.manifest.defaults.sampler.file
        assert (small.get_session_options().intra_op_num_threads == 1) is served
    assert (
        OnnxVelocityField.open(PLANAR3R_DIR / FLOW_INT8_FILE, 2, serial=False)
        .session_for(1, 0)
        .get_session_options()
        .intra_op_num_threads
        == 2
    )
