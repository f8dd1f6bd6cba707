"""Serving defaults per model, chosen by measurement; each carries the reason for its value.

They are written into the manifest at export; `training.evaluate.planar3r` re-measures
the figures quoted here.
"""

from __future__ import annotations

from service.manifest import ConnectivitySpec, Defaults, SamplerSpec

# Stage 5 (service/pipeline/connectivity.py). The tracing step h and seed spacing decide
# how many lockstep continuation steps a 1-D fibre takes (about the largest gap between
# seeds / 2h) and the meeting distance 1.1 h, which must stay below the closest approach
# of two distinct curves (0.28 rad seen on the iiwa pose): h = 0.15. The path spacing is
# the contract's 0.05 rad. The local planner's delta is OMPL's 0.05 scaled up to 0.3 for
# the 4-D fibre, whose edges are long at N = 1000 (lambda and the projection tolerance
# are OMPL's). sigma_min 5e-3 is where Guri & Kantor and Clark & Xie call J singular.
_TRACE = {
    "trace_step_rad": 0.15,
    "trace_max_steps": 200,
    "seed_spacing_rad": 1.0,
    "path_spacing_rad": 0.05,
    "singular_sigma": 5e-3,
}
_PLANNER = {
    "delta_rad": 0.1,
    "lambda_": 2.0,
    "projection_tolerance": 1e-4,
    "neighbours": 8,
    "radius_rad": 1.5,
    "bridge_radius_rad": 3.0,
    "bridge_pairs": 3,
    "bridge_lambda": 3.0,
}
CONNECTIVITY_PLANAR3R = ConnectivitySpec(**_TRACE, **_PLANNER)
CONNECTIVITY_IIWA14_POSE = ConnectivitySpec(**_TRACE, **_PLANNER)
CONNECTIVITY_IIWA14_POSITION = ConnectivitySpec(**_TRACE, **{**_PLANNER, "delta_rad": 0.3})
CONNECTIVITY_REASON = (
    "components decided on the fibre (DESIGN.md stage 5): r = 1 traced whole by "
    "continuation (h 0.15 rad, paths at 0.05 rad), r > 1 a roadmap of edges checked by "
    "the projected local planner (OMPL's lambda 2 and tolerance 1e-4; delta 0.1 rad, "
    "0.3 rad for the 4-D fibre); the figures are in docs/reports"
)

SERVING_DEFAULTS: dict[str, Defaults] = {
    "planar3r-position": Defaults(
        num_samples=1000,
        sampler=SamplerSpec(method="euler", steps=20),
        correction_steps=3,
        damping=1e-3,
        connectivity=CONNECTIVITY_PLANAR3R,
        tolerance_position_m=1e-6,
        tolerance_orientation_rad=1e-6,
        reasons={
            "num_samples": "1000 samples leave at most 0.05 rad between a closed-form SMM point "
            "and a returned configuration at rho = 2 (coverage), at ~0.11 s per target",
            "sampler": "Euler 20 steps: 99.8 % of samples corrected within 1e-6 m vs 98.4 % at "
            "10 and 99.96 % at 50 steps, for 0.11 s vs 0.08 s and 0.20 s per target; counts "
            "50/50 at radius 0.5 from 10 steps up (python -m training.evaluate.planar3r --sweep)",
            "correction_steps": "the paper's 3 DLS steps: keep rate 99.76 %; 5 steps reach "
            "99.95 % for +8 ms per target",
            "damping": "the paper's lambda = 1e-3 (seed Table 4)",
            "connectivity": CONNECTIVITY_REASON,
            "tolerance": "micrometre-exact answers for planners (DESIGN.md)",
        },
    ),
    # Measured by `python -m training.evaluate.iiwa14 --task pose --sweep --targets 40`
    # against the exact components of each target (S-R-S IK), with 6 DLS steps.
    "iiwa14-pose": Defaults(
        num_samples=1000,
        sampler=SamplerSpec(method="euler", steps=20),
        correction_steps=6,
        damping=1e-3,
        connectivity=CONNECTIVITY_IIWA14_POSE,
        tolerance_position_m=1e-6,
        tolerance_orientation_rad=1e-6,
        reasons={
            "num_samples": "exact components found: 90.3 % at 500, 93.1 % at 1000, 95.1 % at "
            "2000 samples; time grows linearly, 1000 keeps a query well under a second",
            "sampler": "Euler 20 steps: keep rate 69.0 % vs 65.9 % at 10 and 69.7 % at 50 "
            "steps (with 6 DLS steps); 50 steps costs 2.5x the sampling time",
            "correction_steps": "the paper's 3 DLS steps keep 50.4 % and left 1 of 40 targets "
            "without a solution; 5 keep 67.0 %, 6 keep 69.0 % and answered 40/40, 8 and 12 "
            "add under 1.5 points for +40 % correction time",
            "damping": "the paper's lambda = 1e-3 (seed Table 4)",
            "connectivity": CONNECTIVITY_REASON,
            "tolerance": "micrometre- and microradian-exact answers for planners (DESIGN.md)",
        },
    ),
    # Measured by `python -m training.evaluate.iiwa14 --task position --sweep --targets 30`.
    "iiwa14-position": Defaults(
        num_samples=1000,
        sampler=SamplerSpec(method="euler", steps=20),
        correction_steps=5,
        damping=1e-3,
        connectivity=CONNECTIVITY_IIWA14_POSITION,
        tolerance_position_m=1e-6,
        tolerance_orientation_rad=1e-6,
        reasons={
            "num_samples": "1000 keeps a query near 0.3 s on 2 cores; the 4-D components "
            "are sparse at that size (nearest neighbours ~0.8 rad apart), 4000 samples "
            "cost 4x the time",
            "sampler": "Euler 20 steps: keep rate 85.4 % vs 80.3 % at 10 and 85.8 % at 50 "
            "steps (3 DLS steps); 50 steps costs 2.5x the sampling time",
            "correction_steps": "keep rate 85.4 % at the paper's 3 DLS steps, 90.8 % at 5, "
            "91.0 % at 8 and 12 (all targets answered at every setting)",
            "damping": "the paper's lambda = 1e-3 (seed Table 4)",
            "connectivity": CONNECTIVITY_REASON,
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
