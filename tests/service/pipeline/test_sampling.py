"""sampling: Euler integration follows the flow exactly, and samples are seeded and wrapped."""

import numpy as np

from service.manifest import AffineNormalisation
from service.models.registry import ServedModel
from service.pipeline.sampling import euler_integrate, sample_configurations

Q_1 = np.array([[0.3, -0.7]], dtype=np.float32)


def exact_field(q_t: np.ndarray, t: np.ndarray, condition: np.ndarray) -> np.ndarray:
    """The exact conditional velocity of the linear path towards Q_1: (q_1 - q_t) / (1 - t)."""
    return ((Q_1 - q_t) / (1 - t)).astype(np.float32)


def test_euler_on_the_exact_field_lands_on_the_data_point() -> None:
    q_0 = np.random.default_rng(0).standard_normal((64, 2)).astype(np.float32)
    landed = euler_integrate(exact_field, q_0, np.zeros((64, 0), np.float32), steps=10)
    np.testing.assert_allclose(landed, np.broadcast_to(Q_1, (64, 2)), atol=1e-5)


def test_samples_are_seeded_denormalised_and_wrapped(planar3r: ServedModel) -> None:
    manifest = planar3r.manifest
    periodic = np.array(manifest.joints.periodic)
    condition = np.zeros(2, np.float32)

    def draw(seed: int, normalisation: AffineNormalisation) -> np.ndarray:
        return sample_configurations(
            planar3r.velocity, condition, 100, 5, normalisation, periodic,
            np.random.default_rng(seed),
        )  # fmt: skip

    first = draw(1, manifest.joint_normalisation)
    np.testing.assert_array_equal(first, draw(1, manifest.joint_normalisation))
    assert not np.array_equal(first, draw(2, manifest.joint_normalisation))
    # Scaling the normalisation up pushes raw angles past pi; periodic joints come back wrapped.
    wide = AffineNormalisation(offset=[0.0] * 3, scale=[30.0] * 3)
    assert np.all(np.abs(draw(1, wide)) <= np.pi)
