"""GET /robots: every served model and the facts from its manifest."""

from __future__ import annotations

from fastapi import APIRouter

from service.api.deps import RegistryDep
from service.api.schemas import error_responses
from service.http.openapi import operation_id
from service.models.registry import ServedModel
from service.wire import RobotOut, RobotsResponse

router = APIRouter(prefix="/robots", tags=["robots"], generate_unique_id_function=operation_id)


def describe(model: ServedModel) -> RobotOut:
    manifest = model.manifest
    return RobotOut(
        robot=manifest.robot,
        task=manifest.task.name,
        model=model.reference,
        joint_names=manifest.joints.names,
        joint_lower=manifest.joints.lower_rad,
        joint_upper=manifest.joints.upper_rad,
        periodic_joints=manifest.joints.periodic,
        redundancy=manifest.redundancy,
        target_position_length=len(manifest.task.position_axes),
        orientation=manifest.task.orientation,
        tool_axis=manifest.task.tool_axis,
        collision_geometry=model.robot_spheres is not None,
        defaults=manifest.defaults.model_dump(),
        training=manifest.training.model_dump(exclude={"config"}),
        quality=None if manifest.quality is None else manifest.quality.model_dump(),
    )


@router.get("", response_model=RobotsResponse, responses=error_responses(401, 503))
async def list_robots(registry: RegistryDep) -> RobotsResponse:
    return RobotsResponse(models=[describe(m) for m in registry.all()])
