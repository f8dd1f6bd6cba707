"""The answers' JSON, encoded straight from the pipeline's arrays.

An answer is mostly floats: an iiwa14 pose answer at N = 500 is about 320 kB of JSON
(each component's configurations and its whole path). Turning every array into Python
lists for pydantic's serialiser (`tolist`, `model_construct`, `model_dump_json`) took
1.5 ms of the server's time per such answer; orjson encodes the numpy arrays as they are
(`OPT_SERIALIZE_NUMPY`, C-contiguous float64 and int64) in 0.46 ms, with no Python float
object per number, to the same JSON values: floats in their shortest round-trip form, so
a client reads back the very float64 the pipeline computed (medians over 20 held-out
targets, 2-core Intel Xeon).

The schema stays the pydantic models of `service/wire.py`: the routes declare them, so
OpenAPI and the Python client read them. The field builders here follow those models
field for field, and tests/service/api/test_answers.py checks that every encoded answer
validates as its model and encodes again to the same values.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import orjson

from service.models.registry import ServedModel
from service.pipeline.types import (
    ComponentRoadmap,
    ComponentSummary,
    FibreStructure,
    SampleCounts,
)

Fields = dict[str, Any]


def encode(fields: Fields) -> bytes:
    """The JSON of an answer's fields: numpy arrays and scalars as they are."""
    return orjson.dumps(fields, option=orjson.OPT_SERIALIZE_NUMPY)


def component_fields(index: int, summary: ComponentSummary, lean: bool = False) -> Fields:
    """A component as `ComponentOut`. `lean`: its representative as its one configuration,
    and no path or roadmap (the self-motion's answer)."""
    configurations = summary.configurations_rad
    if lean:
        configurations = summary.representative_rad[None]
    return {
        "id": index,
        "size": int(summary.size),
        "representative": floats(summary.representative_rad),
        "configurations": floats(configurations),
        "joint_min": floats(summary.joint_min_rad),
        "joint_max": floats(summary.joint_max_rad),
        "max_position_error": float(summary.max_position_error_m),
        "max_orientation_error": float(summary.max_orientation_error_rad),
        "distance_to_reference": _float_or_none(summary.distance_to_reference_rad),
        "nearest_to_reference": floats_or_none(summary.nearest_to_reference_rad),
        "arc_length_rad": _float_or_none(summary.arc_length_rad),
        "closed": None if summary.closed is None else bool(summary.closed),
        "ends": None if summary.ends is None else list(summary.ends),
        "path": None if summary.path is None or lean else floats(summary.path.q_rad),
        "roadmap": None if summary.roadmap is None or lean else roadmap_fields(summary.roadmap),
        "clearance_m": _float_or_none(summary.clearance_m),
        "safest_configuration": floats_or_none(summary.safest_rad),
        "safest_clearance_m": _float_or_none(summary.safest_clearance_m),
    }


def roadmap_fields(roadmap: ComponentRoadmap) -> Fields:
    """A roadmap as `RoadmapOut`."""
    return {"nodes": floats(roadmap.q_rad), "edges": np.ascontiguousarray(roadmap.edges, np.int64)}


def counts_fields(counts: SampleCounts) -> Fields:
    """Where the samples went, as `CountsOut`."""
    return {name: int(value) for name, value in vars(counts).items()}


def structure_fields(structure: FibreStructure) -> Fields:
    """How sure the component structure is, as `StructureOut`."""
    return {
        "near_singular": bool(structure.near_singular),
        "min_singular_value": _float_or_none(structure.min_singular_value),
        "traced": bool(structure.traced),
    }


def model_fields(model: ServedModel) -> Fields:
    """The fields every answer of a model starts with (`SmmResponse`'s first five)."""
    manifest = model.manifest
    return {
        "robot": manifest.robot,
        "task": manifest.task.name,
        "model": model.reference,
        "joint_names": list(manifest.joints.names),
        "redundancy": manifest.redundancy,
    }


def floats(values: np.ndarray) -> np.ndarray:
    """An array as orjson encodes it: C-contiguous float64."""
    return np.ascontiguousarray(values, dtype=np.float64)


def floats_or_none(values: np.ndarray | None) -> np.ndarray | None:
    return None if values is None else floats(values)


def _float_or_none(value: float | None) -> float | None:
    return None if value is None else float(value)
