"""The connect stage's settings, made from the model's `ConnectivitySpec` (the manifest
holds the values and their reasons): one settings object per walker."""

from __future__ import annotations

from service.manifest import ConnectivitySpec
from service.pipeline.connect.local_planner import PlannerSettings
from service.pipeline.connect.roadmap import RoadmapSettings
from service.pipeline.connect.splicing import SpliceSettings
from service.pipeline.connect.trace import TraceSettings

# The splice walk steps h / this: under the closest twins the walk must tell apart (a hop
# is a step longer than lambda x delta; the Panda's stopped ends lie 0.005 to 0.09 rad
# apart at h = 0.15).
SPLICE_DIVISIONS = 32


def trace_settings(spec: ConnectivitySpec) -> TraceSettings:
    return TraceSettings(
        step_rad=spec.trace_step_rad,
        max_steps=spec.trace_max_steps,
        seed_spacing_rad=spec.seed_spacing_rad,
        path_spacing_rad=spec.path_spacing_rad,
    )


def splice_settings(spec: ConnectivitySpec) -> SpliceSettings:
    """Open ends within one trace step are candidates; the walk between them is the local
    planner's (lambda, tolerance) at steps of h / SPLICE_DIVISIONS."""
    return SpliceSettings(
        reach_rad=spec.trace_step_rad,
        planner=PlannerSettings(
            delta_rad=spec.trace_step_rad / SPLICE_DIVISIONS,
            lambda_=spec.lambda_,
            projection_tolerance=spec.projection_tolerance,
        ),
        spacing_rad=spec.path_spacing_rad,
    )


def planner_settings(spec: ConnectivitySpec) -> PlannerSettings:
    return PlannerSettings(
        delta_rad=spec.delta_rad,
        lambda_=spec.lambda_,
        projection_tolerance=spec.projection_tolerance,
        limit_check_rad=spec.limit_check_rad,
    )


def roadmap_settings(spec: ConnectivitySpec) -> RoadmapSettings:
    return RoadmapSettings(
        neighbours=spec.neighbours,
        radius_rad=spec.radius_rad,
        bridge_radius_rad=spec.bridge_radius_rad,
        bridge_pairs=spec.bridge_pairs,
        bridge_lambda=spec.bridge_lambda,
    )
