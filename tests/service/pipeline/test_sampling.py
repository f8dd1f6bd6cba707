"""sampling: Euler integration follows the flow exactly, its time grid goes from 0 to 1 with
steps shortening towards 1 above power 1 (and then integrates a field that steepens near
t = 1 more accurately, against the closed form), a field that pushes a draw outwards cannot
take it to inf or NaN, and samples are seeded and wrapped; with rows per call, each chunk of
draws is integrated on its own, the same on one thread or two."""

from itertools import pairwise

import numpy as np
import pytest

from service.manifest import AffineNormalisation, SamplerSpec
from service.models.registry import ServedModel
from service.pipeline.joint_space import JointLimits
from service.pipeline.sampling import (
    ENVELOPE_MARGIN,
    call_chunks,
    euler_integrate,
    sample_configurations,
    time_grid,
)

Q_1 = np.array([[0.3, -0.7]], dtype=np.float32)


def exact_field(q_t: np.ndarray, t: np.ndarray, condition: np.ndarray) -> np.ndarray:
    """The exact conditional velocity of the linear path towards Q_1: (q_1 - q_t) / (1 - t)."""
    return ((Q_1 - q_t) / (1 - t)).astype(np.float32)


def test_euler_on_the_exact_field_lands_on_the_data_point() -> None:
    q_0 = np.random.default_rng(0).standard_normal((64, 2)).astype(np.float32)
    landed = euler_integrate(exact_field, q_0, np.zeros((64, 0), np.float32), steps=10)
    np.testing.assert_allclose(landed, np.broadcast_to(Q_1, (64, 2)), atol=1e-5)


def test_the_time_grid_runs_from_0_to_1_and_shortens_its_steps_towards_1() -> None:
    np.testing.assert_allclose(time_grid(4), [0.0, 0.25, 0.5, 0.75, 1.0])
    grid = time_grid(20, 1.5)
    steps = np.diff(grid)
    assert grid[0] == 0.0 and grid[-1] == 1.0 and np.all(steps > 0)
    assert np.all(np.diff(steps) < 0)  # each step shorter than the one before
    np.testing.assert_allclose(grid[10], 1 - 0.5**1.5)
    with pytest.raises(ValueError, match="time_power"):
        time_grid(10, 0.5)


def steepening_field(q_t: np.ndarray, t: np.ndarray, condition: np.ndarray) -> np.ndarray:
    """dq/dt = 8 t^7, whose flow from q_0 ends at q_0 + 1 (closed form)."""
    return np.broadcast_to(8 * t**7, q_t.shape).astype(np.float32)


def test_a_grid_dense_near_1_follows_a_field_that_steepens_there_more_closely() -> None:
    q_0 = np.zeros((3, 2), np.float32)
    condition = np.zeros((3, 0), np.float32)
    error = {
        p: float(
            np.abs(euler_integrate(steepening_field, q_0, condition, 10, time_power=p) - 1).max()
        )
        for p in (1.0, 1.5, 2.0)
    }
    # Uniform Euler is the left Riemann sum of 8 t^7: 1 - 0.8 sum_k (k / 10)^7 = 0.353566.
    assert error[1.0] == pytest.approx(0.353566, abs=1e-5)
    assert error[1.5] < 0.75 * error[1.0] and error[2.0] < 0.75 * error[1.0]


def exploding_field(q_t: np.ndarray, t: np.ndarray, condition: np.ndarray) -> np.ndarray:
    """Outwards and growing with |q|, as the iiwa14 position network far outside its data
    (its velocity went 6, 23, 741, 1.5e5 over four Euler steps from a 4.9-sigma draw)."""
    return (q_t * np.abs(q_t) ** 2).astype(np.float32)


def test_a_field_that_pushes_outwards_ends_finite_inside_the_envelope() -> None:
    q_0 = np.random.default_rng(1).standard_normal((200, 7)).astype(np.float32)
    q_0[0, 3] = -4.9
    condition = np.zeros((200, 0), np.float32)
    # Plain explicit Euler on this field overflows to inf / NaN (float32).
    with np.errstate(over="ignore", invalid="ignore"):
        plain = q_0.copy()
        for _ in range(20):
            velocity = exploding_field(plain, plain[:, :1], condition)
            plain = (plain + np.float32(0.05) * velocity).astype(np.float32)
    assert not np.isfinite(plain).all()
    landed = euler_integrate(exploding_field, q_0, condition, steps=20)
    assert np.isfinite(landed).all()
    assert np.abs(landed).max() <= 1.0 + ENVELOPE_MARGIN + 1e-6


def test_samples_are_seeded_denormalised_and_wrapped(planar3r: ServedModel) -> None:
    manifest = planar3r.manifest
    limits = JointLimits.of(manifest.joints)
    condition = np.zeros(2, np.float32)

    def draw(seed: int, normalisation: AffineNormalisation) -> np.ndarray:
        return sample_configurations(
            planar3r.velocity, condition, 100, SamplerSpec(steps=5), normalisation, limits,
            np.random.default_rng(seed),
        )  # fmt: skip

    first = draw(1, manifest.joint_normalisation)
    np.testing.assert_array_equal(first, draw(1, manifest.joint_normalisation))
    assert not np.array_equal(first, draw(2, manifest.joint_normalisation))
    # Scaling the normalisation up pushes raw angles past pi; periodic joints come back wrapped.
    wide = AffineNormalisation(offset=[0.0] * 3, scale=[30.0] * 3)
    assert np.all(np.abs(draw(1, wide)) <= np.pi)


def test_call_chunks_cover_the_samples_in_equal_chunks_of_at_most_call_rows() -> None:
    assert call_chunks(500, None) == [slice(0, 500)]
    assert call_chunks(500, 250) == [slice(0, 250), slice(250, 500)]
    for num_samples, call_rows in [(1000, 250), (501, 250), (300, 250), (7, 1), (3, 10)]:
        chunks = call_chunks(num_samples, call_rows)
        sizes = [chunk.stop - chunk.start for chunk in chunks]
        assert chunks[0].start == 0 and chunks[-1].stop == num_samples
        assert all(a.stop == b.start for a, b in pairwise(chunks))
        assert max(sizes) <= call_rows and max(sizes) - min(sizes) <= 1
        assert len(chunks) == -(-num_samples // call_rows)


@pytest.mark.parametrize("threads", [1, 2])
def test_with_rows_per_call_each_chunk_is_integrated_on_its_own(
    planar3r: ServedModel, threads: int
) -> None:
    """The served int8 network quantises its activations per call, so a draw's sample
    depends on the draws that share its call: with call_rows, exactly on its chunk's."""
    manifest = planar3r.manifest
    limits = JointLimits.of(manifest.joints)
    normalisation = manifest.joint_normalisation
    sampler = manifest.defaults.sampler.model_copy(update={"call_rows": 40, "round_samples": None})
    condition = np.array([0.4, 0.2], np.float32)
    chunked = sample_configurations(
        planar3r.velocity, condition, 100, sampler, normalisation, limits,
        np.random.default_rng(3), threads=threads,
    )  # fmt: skip
    q_0 = np.random.default_rng(3).standard_normal((100, 3), dtype=np.float32)
    conditions = np.ascontiguousarray(np.broadcast_to(condition, (100, 2)))
    alone = [
        euler_integrate(
            planar3r.velocity, q_0[a:b], conditions[a:b], sampler.steps,
            time_power=sampler.time_power,
        )
        for a, b in [(0, 33), (33, 66), (66, 100)]
    ]  # fmt: skip
    expected = limits.wrap(normalisation.denormalise(np.concatenate(alone).astype(np.float64)))
    np.testing.assert_array_equal(chunked, expected)
    whole = sample_configurations(
        planar3r.velocity, condition, 100, sampler.model_copy(update={"call_rows": None}),
        normalisation, limits, np.random.default_rng(3), threads=threads,
    )  # fmt: skip
    assert not np.array_equal(chunked, whole)  # the chunks' own activation scales
