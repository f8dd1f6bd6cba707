"""training.evaluate.scenes.recorder: the recording check changes nothing and records
what it called free.

Its verdicts are the service's CollisionCheck's on the same configurations, and it
records exactly the rows it called free; the answer built with it is `run`'s answer to
the same query (same components, configurations and paths), every accepted member of it
was recorded, and a query that checks nothing records nothing. Its space keeps the walks'
numpy loops, which ask it every step, where the served space's walks are compiled.
"""

from __future__ import annotations

import numpy as np

from service.models.registry import ServedModel
from service.pipeline.run import collision_of, encode, run, space_of
from service.pipeline.types import Query
from training.evaluate.scenes.boxes import scene_target
from training.evaluate.scenes.coal_model import CoalModel
from training.evaluate.scenes.recorder import RecordingCheck, recorded_answer, same_answer
from training.evaluate.served import orientation_wxyz

# A target of seed 3 whose three boxes reject most of its samples (rejected_collision).
SEED, INDEX = 3, 2


def _query(model: ServedModel, coal: CoalModel, check_self: bool, with_boxes: bool = True) -> Query:
    scene = scene_target(model, coal, SEED, INDEX, 4, 0.0)
    obstacles = scene.obstacles if with_boxes else ()
    fk = model.kinematics(scene.q_target_rad[None])
    return Query.for_model(
        model.manifest, position_m=fk.position_m[0].tolist(),
        orientation_wxyz=orientation_wxyz(fk.rotation[0]), seed=3, obstacles=obstacles,
        check_self=check_self,
    )  # fmt: skip


def test_verdicts_are_the_checks_and_the_free_ones_recorded(
    panda_pose_model: ServedModel, panda_coal: CoalModel
) -> None:
    check = collision_of(panda_pose_model, _query(panda_pose_model, panda_coal, True))
    recording = RecordingCheck.like(check)
    limits = panda_pose_model.limits
    q = np.random.default_rng(0).uniform(limits.lower_rad, limits.upper_rad, (300, 7))
    free = recording.free(q)
    np.testing.assert_array_equal(free, check.free(q))
    assert 0 < free.sum() < len(q)
    np.testing.assert_array_equal(recording.recorded(7), np.unique(q[free], axis=0))


def test_the_recorded_answer_is_runs(panda_pose_model: ServedModel, panda_coal: CoalModel) -> None:
    query = _query(panda_pose_model, panda_coal, True)
    result, recording = recorded_answer(panda_pose_model, query)
    assert result.counts.rejected_collision > 0
    assert same_answer(panda_pose_model, query, result)
    assert len(result.components) == len(run(panda_pose_model, query).components)
    recorded = {tuple(row) for row in recording.recorded(7)}
    members = np.concatenate([c.configurations_rad for c in result.components])
    assert len(members) and all(tuple(row) in recorded for row in members)
    unchecked = _query(panda_pose_model, panda_coal, False, with_boxes=False)
    _, nothing = recorded_answer(panda_pose_model, unchecked)
    assert len(nothing.recorded(7)) == 0


def test_the_recording_space_walks_in_numpy_so_every_step_is_seen(
    panda_pose_model: ServedModel, panda_coal: CoalModel
) -> None:
    query = _query(panda_pose_model, panda_coal, True)
    target = encode(panda_pose_model, query)
    check = collision_of(panda_pose_model, query)
    assert check.scene.obstacles  # the served walks check the obstacles in C
    assert space_of(panda_pose_model, target, query.tolerance, check).compiled() is not None
    recording = RecordingCheck.like(check)
    assert space_of(panda_pose_model, target, query.tolerance, recording).compiled() is None
