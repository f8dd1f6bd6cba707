"""rounds: drawing stops after a round whose accepted samples lie on curves already traced.

On the planar 3R at a target 0.5 m out (two loops, elbow up and down, by the closed form
of training/evaluate/references/planar3r.py), with rounds fed from the closed form: a
second round on the loop the first traced stops the drawing; a second round with a
sample on the other loop goes on, traces that loop, and stops after a third round on
known loops; a round with no accepted sample never stops it; num_samples caps the rounds;
the path each sample lies on, found round by round, is the one it lies on among the
final curves.
Through the pipeline (the bundled planar 3R and iiwa14 pose models with a round size
set): the answer counts the samples of the rounds drawn, a multiple of the round size;
its components are the closed form's loops, each traced whole; the same seed gives the
same answer, and a batch gives each query its single answer bitwise. On the iiwa14 pose
(limited joints) rounds of 128 stop after the second round on every held-out target
tried: samples outside the limits a turn from a traced curve are no strays.
"""

from __future__ import annotations

import dataclasses
from contextlib import nullcontext

import numpy as np
import pytest

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.batch import run_batch
from service.pipeline.connect import on_curves
from service.pipeline.rounds import draw_in_rounds
from service.pipeline.run import collision_of, correct_samples, encode, run, space_of
from service.pipeline.types import Query
from tests.service.pipeline.test_batch import assert_same_answer
from training.evaluate.references.planar3r import closed_form_smm
from training.evaluate.served import orientation_wxyz
from training.evaluate.targets import uniform_configurations

TARGET_M = np.array([0.5, 0.0])


def with_rounds(model: ServedModel, round_samples: int) -> ServedModel:
    defaults = model.manifest.defaults
    sampler = defaults.sampler.model_copy(update={"round_samples": round_samples})
    manifest = model.manifest.model_copy(
        update={"defaults": defaults.model_copy(update={"sampler": sampler})}
    )
    return dataclasses.replace(model, manifest=manifest)


@pytest.fixture(scope="module")
def planar_rounds(planar3r: ServedModel) -> ServedModel:
    return with_rounds(planar3r, 40)


def loops() -> tuple[np.ndarray, np.ndarray]:
    up, down = closed_form_smm(TARGET_M, phi_step_rad=0.37)
    return up, down


def rounds_from(
    planar3r: ServedModel, batches: list[np.ndarray], num_samples: int
) -> tuple[int, int]:
    """Rounds drawn and curves traced when round k draws batches[k]."""
    query = Query.for_model(planar3r.manifest, position_m=TARGET_M.tolist(), seed=0)
    target = encode(planar3r, query)
    space = space_of(planar3r, target, query.tolerance, collision_of(planar3r, query))
    supply = iter(batches)

    def draw(count: int) -> np.ndarray:
        rows = next(supply)
        assert len(rows) == count
        return rows

    drawn = draw_in_rounds(
        space,
        num_samples=num_samples,
        round_samples=len(batches[0]),
        draw=draw,
        correct=lambda q: correct_samples(planar3r, space, q),
        spec=planar3r.manifest.defaults.connectivity,
        stage=lambda name: nullcontext(),
    )
    assert len(drawn.correction.q_rad) == sum(len(b) for b in batches[: drawn.rounds])
    # The path each sample on the fibre lies on, found round by round, is the path it lies
    # on among the final curves (a later round's new path found again for every sample).
    q_on_fibre = drawn.correction.q_rad[drawn.acceptance.on_fibre]
    spec = planar3r.manifest.defaults.connectivity
    again = on_curves(drawn.traced.curves, space.limits, q_on_fibre, spec)
    assert drawn.traced.owner.tolist() == again.owner.tolist()
    assert (drawn.traced.owner >= 0).all()  # every closed-form sample lies on a traced loop
    return drawn.rounds, len(drawn.traced.curves.paths)


def test_a_round_on_the_traced_loop_stops_the_drawing(planar3r: ServedModel) -> None:
    up, _ = loops()
    assert rounds_from(planar3r, [up[:3], up[5:8], up[9:12]], num_samples=9) == (2, 1)


def test_a_round_on_a_new_loop_goes_on_and_traces_it(planar3r: ServedModel) -> None:
    up, down = loops()
    batches = [up[:3], np.concatenate([up[4:6], down[:1]]), down[3:6], up[7:10]]
    assert rounds_from(planar3r, batches, num_samples=12) == (3, 2)


def test_a_round_with_nothing_accepted_goes_on_and_num_samples_caps(planar3r: ServedModel) -> None:
    up, _ = loops()
    far = np.full((3, 3), np.nan)  # not finite: never within tolerance
    assert rounds_from(planar3r, [up[:3], far, up[4:7]], num_samples=9) == (3, 1)
    assert rounds_from(planar3r, [far, far.copy()], num_samples=6) == (2, 0)


def test_the_pipeline_answers_the_closed_form_loops_from_fewer_samples(
    planar_rounds: ServedModel,
) -> None:
    query = Query.for_model(
        planar_rounds.manifest, position_m=TARGET_M.tolist(), num_samples=400, seed=3
    )
    result = run(planar_rounds, query)
    assert result.counts.sampled % 40 == 0 and 80 <= result.counts.sampled < 400
    assert len(result.components) == 2
    for component, loop in zip(
        sorted(result.components, key=lambda c: c.representative_rad[1]), loops()[::-1], strict=True
    ):
        assert component.path is not None and component.closed
        # Every closed-form point lies near the traced path: the loop came whole.
        gap = np.abs(
            np.angle(np.exp(1j * (loop[:, None, :] - component.path.q_rad[None, :, :])))
        ).max(axis=2)
        assert gap.min(axis=1).max() < 0.05
    again = run(planar_rounds, query)
    assert_same_answer(again, result)


def test_a_batch_gives_each_query_its_single_answer(planar_rounds: ServedModel) -> None:
    manifest = planar_rounds.manifest
    queries = [
        Query.for_model(manifest, position_m=[0.5, 0.0], num_samples=300, seed=0),
        Query.for_model(manifest, position_m=[1.5, 0.4], num_samples=200, seed=1),
        Query.for_model(manifest, position_m=[0.2, -0.3], num_samples=30, seed=2),  # one round
    ]
    for threads in (1, 2):
        batch = run_batch(planar_rounds, queries, threads=threads)
        for query, result in zip(queries, batch.results, strict=True):
            assert_same_answer(result, run(planar_rounds, query))
    assert batch.results[2].counts.sampled == 30


def test_iiwa14_pose_in_rounds_finds_the_one_shot_components() -> None:
    model = load_model(REPO_MODELS_DIR / "iiwa14-pose", threads=1)
    rounds = with_rounds(model, 64)
    q = np.array([[0.3, 0.8, -0.4, -1.2, 0.5, 0.9, 0.1]])
    fk = model.kinematics(q)
    query = Query.for_model(
        model.manifest,
        position_m=fk.position_m[0].tolist(),
        orientation_wxyz=orientation_wxyz(fk.rotation[0]),
        seed=4,
    )
    one_shot, in_rounds = run(model, query), run(rounds, query)
    assert in_rounds.counts.sampled < one_shot.counts.sampled
    assert in_rounds.counts.sampled % 64 == 0
    assert len(in_rounds.components) == len(one_shot.components)
    arcs = sorted(c.arc_length_rad or 0.0 for c in one_shot.components)
    assert sorted(c.arc_length_rad or 0.0 for c in in_rounds.components) == pytest.approx(
        arcs, rel=1e-3, abs=0.05
    )


def test_iiwa14_pose_rounds_stop_once_a_round_finds_nothing_new() -> None:
    """On an arm with limited joints a sample outside the limits on a traced curve is often
    a turn of a joint away from the traced point beside it; measured on the torus it is no
    stray, so a round whose samples all lie on traced curves ends the drawing (measured in
    the limited joints' metric, every round found such strays and all N were drawn)."""
    model = load_model(REPO_MODELS_DIR / "iiwa14-pose", threads=1)
    rounds = with_rounds(model, 128)
    for seed, q in enumerate(uniform_configurations(model.limits, 5, 7)):
        fk = model.kinematics(q[None])
        query = Query.for_model(
            model.manifest,
            position_m=fk.position_m[0].tolist(),
            orientation_wxyz=orientation_wxyz(fk.rotation[0]),
            seed=seed,
        )
        assert run(rounds, query).counts.sampled == 256, f"target {seed}"
