"""batch: every query of a batch gets `run`'s answer to the bit (samples, corrected
configurations, components, paths, counts), whether one thread answers the queries or
several answer them at once, on the planar 3R and the iiwa14 pose; a target's timings
add up its stages; a deadline that passes mid-batch returns the queries answered before
it, in order, and names the stage it stopped, whatever the threads; each answer is handed
to the listener in order, and an error the listener raises stops the batch, the queries
not yet started never starting; every query answered, sent or not (one under way when the
batch stopped), is heard by `on_computed`, each its `run` answer."""

from __future__ import annotations

import time

import numpy as np
import pytest

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.batch import run_batch
from service.pipeline.deadline import Deadline
from service.pipeline.joint_space import JointLimits
from service.pipeline.run import run
from service.pipeline.types import (
    Query,
    SmmResult,
)
from tests.support.watched import condition_of, slow_on, watched
from training.evaluate.served import orientation_wxyz


def assert_same_answer(batch: SmmResult, single: SmmResult) -> None:
    """Bitwise on every array; equal on every count and flag; timings aside."""
    assert batch.counts == single.counts
    assert batch.structure == single.structure
    assert len(batch.components) == len(single.components)
    for a, b in zip(batch.components, single.components, strict=True):
        for name in ("representative_rad", "configurations_rad", "joint_min_rad", "joint_max_rad"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        assert a.size == b.size and a.closed == b.closed
        assert a.max_position_error_m == b.max_position_error_m
        assert a.max_orientation_error_rad == b.max_orientation_error_rad
        assert a.distance_to_reference_rad == b.distance_to_reference_rad
        assert a.arc_length_rad == b.arc_length_rad
        assert (a.path is None) == (b.path is None)
        if a.path is not None and b.path is not None:
            assert np.array_equal(a.path.q_rad, b.path.q_rad)


def planar_queries(model: ServedModel) -> list[Query]:
    """Targets along a path, seeds and sizes that differ, one out of reach, one with options."""
    manifest = model.manifest
    return [
        Query.for_model(manifest, position_m=[0.5, 0.0], num_samples=300, seed=0),
        Query.for_model(manifest, position_m=[0.5, 0.2], num_samples=200, seed=11),
        Query.for_model(manifest, position_m=[3.5, 0.0], num_samples=100, seed=2),
        Query.for_model(
            manifest,
            position_m=[0.3, -0.6],
            num_samples=250,
            seed=5,
            reference_rad=[0.1, 1.9, 2.6],
            max_configurations_per_component=7,
            include_paths=False,
            tolerance_position_m=1e-8,
        ),
        Query.for_model(manifest, position_m=[0.3, -0.6], num_samples=250, seed=6),
    ]


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_each_answer_is_the_single_query_answer_bitwise(
    planar3r: ServedModel, threads: int
) -> None:
    queries = planar_queries(planar3r)
    batch = run_batch(planar3r, queries, threads=threads)
    assert batch.complete and batch.deadline_error is None
    assert len(batch.results) == len(queries)
    for query, result in zip(queries, batch.results, strict=True):
        assert_same_answer(result, run(planar3r, query))
    # Each its own query's draw: rounds of 128 (the planar 3R's) stop after the second
    # round at 300 (both loops traced from the first); 200 and 250 end with their second
    # round, short of 128; 100 is drawn at once.
    assert [r.counts.sampled for r in batch.results] == [256, 200, 100, 250, 250]
    assert not batch.results[2].components  # out of reach: no_solution, in its place


@pytest.mark.parametrize("threads", [1, 2])
def test_each_answer_is_handed_over_in_order_as_it_is_ready(
    planar3r: ServedModel, threads: int
) -> None:
    queries = planar_queries(planar3r)
    heard: list[tuple[int, SmmResult]] = []
    batch = run_batch(
        planar3r, queries, threads=threads, on_answer=lambda i, r: heard.append((i, r))
    )
    assert [i for i, _ in heard] == list(range(len(queries)))
    assert all(r is result for (_, r), result in zip(heard, batch.results, strict=True))


class Enough(Exception):
    pass


@pytest.mark.parametrize("threads", [1, 2])
def test_an_error_from_the_listener_stops_the_batch(planar3r: ServedModel, threads: int) -> None:
    queries = [
        Query.for_model(planar3r.manifest, position_m=[0.5, 0.01 * i], num_samples=50, seed=i)
        for i in range(12)
    ]
    first_two = {condition_of(planar3r, q.position_m) for q in queries[:2]}
    sampled: set[bytes] = set()  # the conditions of the targets whose sampling began

    def watch(condition: np.ndarray) -> None:
        sampled.add(condition.tobytes())
        if condition.tobytes() not in first_two:
            time.sleep(0.5)  # the workers' next targets are under way when the batch stops

    counted = watched(planar3r, watch)
    answered: list[int] = []
    computed: list[SmmResult] = []

    def stop_after_the_second(index: int, result: SmmResult) -> None:
        answered.append(index)
        if index == 1:
            raise Enough

    with pytest.raises(Enough):
        run_batch(
            counted, queries, threads=threads, on_answer=stop_after_the_second,
            on_computed=computed.append,
        )  # fmt: skip
    assert answered == [0, 1]  # nothing is handed over after the error
    # Those under way finished, the rest were never started.
    assert 2 <= len(sampled) <= 2 + threads
    # Every query whose sampling began was answered and heard, the unsent ones too, each
    # the `run` answer of one of the queries.
    assert len(computed) == len(sampled)
    singles = [run(planar3r, q).components[0].configurations_rad for q in queries]
    for result in computed:
        heard = result.components[0].configurations_rad
        assert sum(np.array_equal(heard, single) for single in singles) == 1


def test_a_changed_seed_changes_only_its_own_answer(planar3r: ServedModel) -> None:
    """The test above can fail: answers are not equal for any two seeds."""
    queries = planar_queries(planar3r)
    other = Query.for_model(planar3r.manifest, position_m=[0.5, 0.2], num_samples=200, seed=12)
    batch = run_batch(planar3r, [queries[0], other])
    assert_same_answer(batch.results[0], run(planar3r, queries[0]))
    with pytest.raises(AssertionError):
        assert_same_answer(batch.results[1], run(planar3r, queries[1]))


@pytest.fixture(scope="module")
def iiwa14_pose() -> ServedModel:
    return load_model(REPO_MODELS_DIR / "iiwa14-pose", threads=1)


def test_iiwa14_pose_answers_are_the_single_answers_bitwise(iiwa14_pose: ServedModel) -> None:
    manifest = iiwa14_pose.manifest
    limits = JointLimits.of(manifest.joints)
    q_targets = np.random.default_rng(3).uniform(
        limits.lower_rad, limits.upper_rad, size=(3, len(limits.lower_rad))
    )
    queries = []
    for seed, q in enumerate(q_targets):
        fk = iiwa14_pose.kinematics(q[None])
        queries.append(
            Query.for_model(
                manifest,
                position_m=fk.position_m[0].tolist(),
                orientation_wxyz=orientation_wxyz(fk.rotation[0]),
                num_samples=80,
                seed=seed,
            )
        )
    batch = run_batch(iiwa14_pose, queries, threads=2)
    for query, result in zip(queries, batch.results, strict=True):
        assert result.components  # every target is the FK of a configuration: reachable
        assert_same_answer(result, run(iiwa14_pose, query))


def test_a_targets_timings_add_up_its_stages(planar3r: ServedModel) -> None:
    batch = run_batch(planar3r, planar_queries(planar3r)[:2])
    for result in batch.results:
        timings = result.timings
        assert timings.total_ms == pytest.approx(sum(timings.stage_ms.values()))
        assert set(timings.stage_ms) == {
            "encode",
            "sample",
            "correct",
            "accept",
            "connect",
            "summarise",
        }
    assert batch.total_ms > 0


@pytest.mark.parametrize("threads", [1, 2])
def test_a_deadline_mid_batch_returns_the_answers_before_it(
    planar3r: ServedModel, threads: int
) -> None:
    queries = [
        Query.for_model(planar3r.manifest, position_m=position, num_samples=50, seed=1)
        for position in ([0.5, 0.0], [0.5, 0.2], [0.5, 0.4])
    ]
    deadline = Deadline.after(2.0)
    slow = slow_on(planar3r, [0.5, 0.2], deadline)
    batch = run_batch(slow, queries, deadline, threads=threads)
    assert not batch.complete and batch.deadline_error is not None
    assert batch.deadline_error.stage == "sample"
    assert len(batch.results) == 1  # the first target, answered before the deadline
    assert_same_answer(batch.results[0], run(planar3r, queries[0]))


def test_an_expired_deadline_answers_nothing_whatever_the_threads(planar3r: ServedModel) -> None:
    queries = planar_queries(planar3r)[:3]
    expired = Deadline(budget_s=1.0, expires_at_s=time.monotonic() - 1.0)
    for threads in (1, 2):
        batch = run_batch(planar3r, queries, expired, threads=threads)
        assert batch.results == [] and batch.deadline_error is not None
        assert batch.deadline_error.stage == "sample"
