"""tracing: seeds are spread on the joint torus, a whole turn apart counting as no apart,
an angle a rounding below 0 (which np.mod maps onto 2 pi itself) is a valid seed, and the
seeds are the in-order greedy choice."""

import numpy as np
import pytest

from service.pipeline.joint_space import joint_distance
from service.pipeline.tracing import spread_seeds


def test_seeds_are_spread_on_the_torus_and_survive_angles_rounding_to_2_pi() -> None:
    q = np.array(
        [
            [-1e-17, 0.0, 0.0],  # np.mod(-1e-17, 2 pi) == 2 pi in float64
            [2 * np.pi - 1e-3, 0.0, 0.0],  # 1e-3 rad from the first, round the circle
            [1.0, 0.0, 0.0],
            [1.05, 0.0, 0.0],
            [-2.0, 0.5, 0.0],
        ]
    )
    seeds = spread_seeds(q, spacing_rad=0.2)
    np.testing.assert_array_equal(seeds, q[[0, 2, 4]])


@pytest.mark.parametrize("spacing", [0.3, 1.0, 2.5])
def test_seeds_are_the_greedy_choice_in_order(spacing: float) -> None:
    """The batched choice (distances from circle embeddings, the torus distance only where
    they cannot decide) picks exactly the points the one-by-one greedy choice picks."""
    rng = np.random.default_rng(6)
    q = rng.uniform(-4.0, 4.0, (300, 4))
    q[150:] = q[:150] + rng.normal(scale=0.2, size=(150, 4))  # pairs near each other
    chosen: list[int] = []
    for i in range(len(q)):
        if all(joint_distance(q[i], q[j], np.ones(4, bool)) > spacing for j in chosen):
            chosen.append(i)
    np.testing.assert_array_equal(spread_seeds(q, spacing), q[chosen])
