"""Serving defaults per model, chosen by measurement; each carries the reason for its value.

They are written into the manifest at export; `training.evaluate.planar3r` re-measures
the figures quoted here.
"""

from __future__ import annotations

from service.manifest import Defaults, SamplerSpec

SERVING_DEFAULTS: dict[str, Defaults] = {
    "planar3r-position": Defaults(
        num_samples=1000,
        sampler=SamplerSpec(method="euler", steps=20),
        correction_steps=3,
        damping=1e-3,
        cluster_radius_rad=0.3,
        tolerance_position_m=1e-6,
        tolerance_orientation_rad=1e-6,
        reasons={
            "num_samples": "TODO",
            "sampler": "TODO",
            "correction_steps": "TODO",
            "damping": "paper (seed Table 4): lambda = 1e-3",
            "cluster_radius_rad": "TODO",
            "tolerance": "micrometre-exact answers for planners (DESIGN.md)",
        },
    ),
}


def serving_defaults(model_id: str) -> Defaults:
    try:
        return SERVING_DEFAULTS[model_id]
    except KeyError:
        raise ValueError(
            f"no serving defaults for {model_id!r}; choose from {sorted(SERVING_DEFAULTS)}"
        ) from None
