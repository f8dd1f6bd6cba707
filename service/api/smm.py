"""POST /smm: the self-motion manifolds of one target."""

from __future__ import annotations

from fastapi import APIRouter

from service.api.deps import RegistryDep, SettingsDep
from service.errors import LimitExceededError, RequestFieldError
from service.pipeline.components import ComponentSummary
from service.pipeline.run import Query, SmmResult, run
from service.registry import ServedModel
from service.schemas import ComponentOut, Counts, SmmRequest, SmmResponse, Timings

router = APIRouter(prefix="/smm", tags=["smm"])


def to_query(body: SmmRequest, model: ServedModel, max_num_samples: int) -> Query:
    """Fill the model's defaults into the request and check what depends on the model."""
    defaults = model.manifest.defaults
    num_samples = defaults.num_samples if body.num_samples is None else body.num_samples
    if num_samples > max_num_samples:
        raise LimitExceededError(
            f"num_samples must be at most {max_num_samples} on this server, got {num_samples}"
        )
    if body.tolerance.orientation is not None and not model.manifest.task.orientation:
        raise RequestFieldError(
            ("body", "tolerance", "orientation"),
            "tolerance.orientation applies only to the pose task",
        )
    orientation, tolerance = body.target.orientation, body.tolerance
    return Query(
        position_m=body.target.position,
        orientation_wxyz=None if orientation is None else orientation.wxyz(),
        num_samples=num_samples,
        seed=body.seed,
        tolerance_position_m=(
            defaults.tolerance_position_m if tolerance.position is None else tolerance.position
        ),
        tolerance_orientation_rad=(
            defaults.tolerance_orientation_rad
            if tolerance.orientation is None
            else tolerance.orientation
        ),
        reference_rad=body.reference_configuration,
        max_configurations_per_component=body.max_configurations_per_component,
    )


def _component_out(index: int, summary: ComponentSummary) -> ComponentOut:
    nearest = summary.nearest_to_reference_rad
    return ComponentOut(
        id=index,
        size=summary.size,
        representative=summary.representative_rad.tolist(),
        configurations=summary.configurations_rad.tolist(),
        joint_min=summary.joint_min_rad.tolist(),
        joint_max=summary.joint_max_rad.tolist(),
        max_position_error=summary.max_position_error_m,
        max_orientation_error=summary.max_orientation_error_rad,
        distance_to_reference=summary.distance_to_reference_rad,
        nearest_to_reference=None if nearest is None else nearest.tolist(),
    )


def to_response(model: ServedModel, result: SmmResult) -> SmmResponse:
    manifest = model.manifest
    t = result.timings
    return SmmResponse(
        robot=manifest.robot,
        task=manifest.task.name,
        model=model.reference,
        joint_names=manifest.joints.names,
        redundancy=manifest.redundancy,
        status="ok" if result.components else "no_solution",
        counts=Counts(**vars(result.counts)),
        components=[_component_out(i, s) for i, s in enumerate(result.components)],
        timings_ms=Timings(
            encode=t.encode_ms,
            sample=t.sample_ms,
            correct=t.correct_ms,
            accept=t.accept_ms,
            cluster=t.cluster_ms,
            total=t.total_ms,
        ),
    )


@router.post("", response_model=SmmResponse)
def post_smm(body: SmmRequest, registry: RegistryDep, settings: SettingsDep) -> SmmResponse:
    # A plain `def`: FastAPI runs it in its thread pool, so the numerical work
    # never blocks the event loop.
    model = registry.get(body.robot, body.task)
    return to_response(model, run(model, to_query(body, model, settings.max_num_samples)))
