"""A Python client of the SMM service: typed calls over HTTP, with timeouts and retries.

Imports httpx, pydantic and the wire models (`service.wire`) only, never numpy, fastapi
or onnxruntime, so a planner can use it without the server's dependencies (a test
imports it with those blocked). The request and response models are the server's own.

    from service.client import QuaternionIn, SmmClient, SmmRequest, TargetIn

    with SmmClient("http://127.0.0.1:8000") as smm:
        answer = smm.smm(SmmRequest(robot="planar3r", task="position",
                                    target=TargetIn(position=[0.5, 0.0])))
        print(len(answer.components))
"""

from service.client.client import SmmClient
from service.client.errors import (
    FieldError,
    SmmClientError,
    SmmConnectionError,
    SmmHTTPError,
    SmmTimeoutError,
    SmmTransportError,
)
from service.client.retry import RetryEvent, RetryPolicy
from service.wire import (
    BatchItemOut,
    BatchTargetIn,
    CollisionIn,
    CollisionOut,
    ComponentOut,
    CountsOut,
    GoalIn,
    LivenessResponse,
    ObstacleIn,
    QuaternionIn,
    ReadinessResponse,
    RoadmapOut,
    RobotOut,
    SelfMotionRequest,
    SelfMotionResponse,
    SmmBatchEnd,
    SmmBatchHead,
    SmmBatchRequest,
    SmmBatchResponse,
    SmmRequest,
    SmmResponse,
    StructureOut,
    TargetIn,
    ToleranceIn,
)

__all__ = [
    "BatchItemOut",
    "BatchTargetIn",
    "CollisionIn",
    "CollisionOut",
    "ComponentOut",
    "CountsOut",
    "FieldError",
    "GoalIn",
    "LivenessResponse",
    "ObstacleIn",
    "QuaternionIn",
    "ReadinessResponse",
    "RetryEvent",
    "RetryPolicy",
    "RoadmapOut",
    "RobotOut",
    "SelfMotionRequest",
    "SelfMotionResponse",
    "SmmBatchEnd",
    "SmmBatchHead",
    "SmmBatchRequest",
    "SmmBatchResponse",
    "SmmClient",
    "SmmClientError",
    "SmmConnectionError",
    "SmmHTTPError",
    "SmmRequest",
    "SmmResponse",
    "SmmTimeoutError",
    "SmmTransportError",
    "StructureOut",
    "TargetIn",
    "ToleranceIn",
]
