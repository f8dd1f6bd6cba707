"""chain: the compiled kernel on chain.json gives pytorch-kinematics' FK and geometric Jacobian.

For the iiwa14 and planar 3R URDFs and for a URDF with fixed joints between movable ones,
oblique and negative axes, arbitrary origin rpy and a continuous joint
(tests/support/chains.py), the kernel built from `training.kinematics.chain_spec` equals
pytorch-kinematics (`load_chain` + `ForwardKinematics`, what kinematics.onnx is exported
from) to 1e-12 in position, rotation and Jacobian. Its Jacobian equals central finite
differences of its own FK (linear rows against the position, angular rows against the
rotation increment). A non-finite joint value spoils only its own row; a batch's rows
answered in parts, and calls from several threads at once, give the one-call answer;
any batch size, zero included, has the right shapes; chain.json that is not a rigid
chain with unit axes is refused, naming the file.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError
from scipy.spatial.transform import Rotation

from service.errors import ModelVerificationError
from service.manifest import REPO_MODELS_DIR, ChainSpec
from service.models.chain import SerialChainKinematics
from tests.support.chains import (
    TWISTED_END_EFFECTOR,
    configurations,
    pytorch_kinematics_answer,
    write_twisted_urdf,
)
from training.kinematics import chain_spec, load_chain

ROBOTS = REPO_MODELS_DIR / "robots"


@pytest.fixture(scope="module")
def twisted_urdf(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_twisted_urdf(tmp_path_factory.mktemp("twisted"))


def urdf_case(name: str, twisted_urdf: Path) -> tuple[Path, str]:
    if name == "twisted":
        return twisted_urdf, TWISTED_END_EFFECTOR
    return ROBOTS / f"{name}.urdf", "ee"


def kernel(urdf: Path, end_effector_link: str) -> SerialChainKinematics:
    return SerialChainKinematics(chain_spec(load_chain(urdf, end_effector_link)))


@pytest.fixture(scope="module")
def twisted(twisted_urdf: Path) -> SerialChainKinematics:
    return kernel(twisted_urdf, TWISTED_END_EFFECTOR)


@pytest.mark.parametrize("name", ["iiwa14", "planar3r", "twisted"])
def test_equals_pytorch_kinematics(name: str, twisted_urdf: Path) -> None:
    urdf, end_effector = urdf_case(name, twisted_urdf)
    q = configurations(urdf, end_effector, 2000, seed=0)
    answer = kernel(urdf, end_effector)(q)
    expected = pytorch_kinematics_answer(urdf, end_effector, q)
    actual = (answer.position_m, answer.rotation, answer.jacobian)
    for a, e in zip(actual, expected, strict=True):
        assert a.shape == e.shape
        np.testing.assert_allclose(a, e, rtol=0, atol=1e-12)


def test_the_twisted_chain_folds_its_fixed_joints(twisted_urdf: Path) -> None:
    """Five movable joints out of nine: the fixed ones are folded, not joints of the kernel."""
    spec = chain_spec(load_chain(twisted_urdf, TWISTED_END_EFFECTOR))
    assert spec.joint_names == ["j1", "j2", "j3", "j4", "j5"]
    assert (spec.base_link, spec.end_effector_link) == ("base", "tool")
    np.testing.assert_allclose(spec.joints[3].axis, np.array([-1, 2, 0.5]) / np.sqrt(5.25))


def test_angles_beyond_pi_and_near_the_half_turn(
    twisted: SerialChainKinematics, twisted_urdf: Path
) -> None:
    """Exact also at the half turn, beyond it and several turns away."""
    special = np.array([np.pi, -np.pi, np.nextafter(np.pi, 0), 3 * np.pi, 7.0, -12.5, 0.0, 1e-9])
    q = np.tile(special[:, None], (1, 5))  # every joint at each special angle
    q[:, 2] = special[::-1]
    answer = twisted(q)
    expected = pytorch_kinematics_answer(twisted_urdf, TWISTED_END_EFFECTOR, q)
    for a, e in zip((answer.position_m, answer.rotation, answer.jacobian), expected, strict=True):
        np.testing.assert_allclose(a, e, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["iiwa14", "twisted"])
def test_jacobian_equals_central_differences_of_its_own_fk(name: str, twisted_urdf: Path) -> None:
    urdf, end_effector = urdf_case(name, twisted_urdf)
    kinematics = kernel(urdf, end_effector)
    q = configurations(urdf, end_effector, 200, seed=1)
    jacobian = kinematics(q).jacobian  # (B, 6, n)
    step = 1e-6
    for j in range(q.shape[1]):
        dq = np.zeros(q.shape[1])
        dq[j] = step
        forward, backward = kinematics(q + dq), kinematics(q - dq)
        linear = (forward.position_m - backward.position_m) / (2 * step)
        # Angular velocity: log of the rotation increment R(q + h e_j) R(q - h e_j)^T.
        increment = forward.rotation @ np.swapaxes(backward.rotation, 1, 2)
        angular = Rotation.from_matrix(increment).as_rotvec() / (2 * step)
        np.testing.assert_allclose(jacobian[:, :3, j], linear, rtol=0, atol=1e-8)
        np.testing.assert_allclose(jacobian[:, 3:, j], angular, rtol=0, atol=1e-8)


def test_a_non_finite_joint_value_spoils_only_its_row(twisted: SerialChainKinematics) -> None:
    q = np.random.default_rng(2).uniform(-1, 1, (9, 5))
    q[2, 0], q[5, 3], q[7, 4] = np.nan, np.inf, -np.inf
    bad = np.zeros(9, dtype=bool)
    bad[[2, 5, 7]] = True
    answer = twisted(q)
    for rows in (answer.position_m, answer.rotation, answer.jacobian):
        assert np.all(np.isfinite(rows[~bad]))
    assert np.all(np.isnan(answer.position_m[bad])) and np.all(np.isnan(answer.rotation[bad]))
    assert np.all(np.isnan(answer.jacobian[bad][:, :3]))  # every lever arm reaches p_ee
    clean = twisted(q[~bad])
    np.testing.assert_array_equal(answer.position_m[~bad], clean.position_m)
    np.testing.assert_array_equal(answer.rotation[~bad], clean.rotation)
    np.testing.assert_array_equal(answer.jacobian[~bad], clean.jacobian)


def test_rows_and_threads_give_the_one_call_answer(twisted: SerialChainKinematics) -> None:
    q = np.random.default_rng(3).uniform(-3, 3, (50, 5))
    whole = twisted(q)
    for start in range(0, 50, 7):
        part = twisted(q[start : start + 7])
        np.testing.assert_array_equal(part.jacobian, whole.jacobian[start : start + 7])
        np.testing.assert_array_equal(part.rotation, whole.rotation[start : start + 7])
    batches = [np.random.default_rng(seed).uniform(-3, 3, (300 + seed, 5)) for seed in range(16)]
    alone = [twisted(b).jacobian for b in batches]
    with ThreadPoolExecutor(max_workers=4) as pool:
        together = list(pool.map(lambda b: twisted(b).jacobian, batches))
    for a, b in zip(alone, together, strict=True):
        np.testing.assert_array_equal(a, b)


def test_shapes_for_any_batch_and_refusal_of_a_wrong_width(twisted: SerialChainKinematics) -> None:
    for batch in (0, 1, 5):
        answer = twisted(np.zeros((batch, 5)))
        assert answer.position_m.shape == (batch, 3)
        assert answer.rotation.shape == (batch, 3, 3)
        assert answer.jacobian.shape == (batch, 6, 5)
        assert answer.jacobian.flags.c_contiguous and answer.rotation.flags.c_contiguous
    with pytest.raises(ValueError, match=r"shape \(4, 3\); expected \(B, 5\)"):
        twisted(np.zeros((4, 3)))


def _spec_dict() -> dict[str, object]:
    spec = chain_spec(load_chain(ROBOTS / "planar3r.urdf", "ee"))
    return spec.model_dump()


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda s: s["joints"][1].update(axis=[0.0, 0.0, 2.0]), "axis .* is not a unit 3-vector"),
        (lambda s: s["joints"][0]["origin"][0].__setitem__(0, 1.5), "not a rotation"),
        (lambda s: s["tip"][3].__setitem__(0, 0.1), r"tip: last row"),
        (lambda s: s["tip"].pop(), "tip: not a finite 4x4 transform"),
        (lambda s: s.update(joints=[]), "at least 1 item"),
    ],
)
def test_a_chain_that_is_not_rigid_with_unit_axes_is_refused(change: object, message: str) -> None:
    spec = _spec_dict()
    change(spec)  # type: ignore[operator]
    with pytest.raises(ValidationError, match=message):
        ChainSpec.model_validate(spec)


def test_an_unreadable_chain_file_is_refused_naming_it(tmp_path: Path) -> None:
    path = tmp_path / "chain.json"
    path.write_text('{"format_version": 1}')
    with pytest.raises(ModelVerificationError, match=r"chain\.json: unreadable chain"):
        SerialChainKinematics.from_file(path)
