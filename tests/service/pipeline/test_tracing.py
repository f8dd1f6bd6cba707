"""tracing: seeds are spread on the joint torus, a whole turn apart counting as no apart,
and an angle a rounding below 0 (which np.mod maps onto 2 pi itself) is a valid seed."""

import numpy as np

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
