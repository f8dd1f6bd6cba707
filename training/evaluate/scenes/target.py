"""One target of the scene section: its scene, the service's answer in it, that answer
checked by coal, its free pieces found (pose; a position where its robot's reference has
a graph to cut, position.py; not for the tool-axis task, which has no such reference),
the free space the check loses, and its four timings.
Everything is a JSON-ready dict, with the POST /smm body that replays it."""

from __future__ import annotations

from dataclasses import asdict

import numpy as np

from service.models.registry import ServedModel
from service.pipeline.arrays import FloatArray
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.collision.scene import Obstacle, Scene
from service.pipeline.types import SmmResult
from training.evaluate.methods import returned_points
from training.evaluate.scenes.boxes import SceneTarget, request_body, target_fields
from training.evaluate.scenes.coal_model import CoalModel
from training.evaluate.scenes.exactness import Exactness, recorded_sample
from training.evaluate.scenes.pieces import recall
from training.evaluate.scenes.position import POSITION_REFERENCES, position_recall
from training.evaluate.scenes.recorder import recorded_answer, same_answer
from training.evaluate.scenes.reference import free_pieces_of_pose
from training.evaluate.scenes.timing import query_for, time_ways_ms
from training.evaluate.truth import ground_truth

# Exact points of a fibre without free-piece reference (position, axis) checked for the
# free space lost, per target.
FIBRE_POINTS = 1000


def _returned(result: SmmResult, num_joints: int) -> tuple[FloatArray, np.ndarray]:
    """Every returned configuration (members, path points) and its component."""
    returned = returned_points(
        [(c.configurations_rad, c.path) for c in result.components], num_joints
    )
    return returned.q_rad, returned.labels


def free_space_lost(
    model: ServedModel, coal_free: FloatArray, obstacles: tuple[Obstacle, ...], margin_m: float
) -> dict[str, int]:
    """Reference points free by coal, and those of them the service's check calls not free."""
    lost = ~sphere_check(model, obstacles, margin_m).free(coal_free)
    return {"coal_free": len(coal_free), "lost": int(lost.sum())}


def sphere_check(
    model: ServedModel, obstacles: tuple[Obstacle, ...], margin_m: float
) -> CollisionCheck:
    """The service's check of a query in this scene, self-collision on."""
    return CollisionCheck(model.robot_spheres, Scene(obstacles), True, margin_m)


def fibre_points(model: ServedModel, q_target_rad: FloatArray, seed: int) -> FloatArray:
    """At most FIBRE_POINTS exact points of a position or axis target's fibre, at random (the
    kinematic report's ground truth, its grid drawn with `seed`)."""
    points = ground_truth(model, q_target_rad, seed).points
    if len(points) <= FIBRE_POINTS:
        return points
    return points[np.random.default_rng(seed).choice(len(points), FIBRE_POINTS, replace=False)]


def evaluate_target(
    model: ServedModel,
    coal: CoalModel,
    scene: SceneTarget,
    timing_scene: tuple[Obstacle, ...],
    margin_m: float,
) -> dict[str, object]:
    """The scene section's measures of one target (module docstring)."""
    manifest = model.manifest
    n = manifest.joints.count
    target = target_fields(model, scene.q_target_rad)
    obstacles = scene.obstacles
    query = query_for(model, target, obstacles, True, margin_m, scene.index)
    result, check = recorded_answer(model, query)
    returned, labels = _returned(result, n)
    recorded = recorded_sample(check.recorded(n), scene.index)
    times, answers = time_ways_ms(model, target, obstacles, timing_scene, margin_m, scene.index)
    entry: dict[str, object] = {
        "index": scene.index,
        "q_target_rad": scene.q_target_rad.tolist(),
        "boxes_asked": scene.boxes_asked,
        "request": request_body(model, scene, margin_m),
        "components": len(result.components),
        "near_singular": result.structure.near_singular,
        "counts": asdict(result.counts),
        "returned": asdict(Exactness.of(coal, returned, obstacles, margin_m)),
        "recorded_total": len(check.recorded(n)),
        "recorded": asdict(Exactness.of(coal, recorded, obstacles, margin_m)),
        "time_ms": times,
        "timing_obstacles": len(timing_scene),
        "same_as_run": same_answer(model, query, result),
    }
    if manifest.task.orientation and manifest.redundancy == 1:
        pieces = free_pieces_of_pose(model, coal, scene.q_target_rad, obstacles, margin_m)
        sphere_free = sphere_check(model, obstacles, margin_m).free(pieces.q_rad)
        kinematic = _returned(answers["nothing_checked"], n)[0]
        found = recall(pieces, sphere_free, returned, labels, model.limits.periodic, kinematic)
        entry["recall"] = asdict(found)
        coal_free = pieces.q_rad[pieces.label >= 0]
    else:
        position_task = not manifest.task.orientation and manifest.task.tool_axis is None
        if position_task and manifest.robot in POSITION_REFERENCES:
            found, steps = position_recall(
                model, coal, sphere_check(model, obstacles, margin_m).free,
                scene.q_target_rad, obstacles, margin_m, returned, labels,
                _returned(answers["nothing_checked"], n)[0],
            )  # fmt: skip
            entry["recall"] = {**asdict(found), "grid_steps": steps}
        points = fibre_points(model, scene.q_target_rad, scene.index)
        coal_free = points[coal.free(points, obstacles, margin_m)]
    entry["free_space"] = free_space_lost(model, coal_free, obstacles, margin_m)
    return entry
