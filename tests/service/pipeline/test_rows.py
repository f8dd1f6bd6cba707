"""rows: the chunks cover every row once, in order, none shorter than MIN_CHUNK_ROWS unless
there is only one; a call over rows runs its chunks on helper threads and returns their
results in the chunks' order; work set aside runs on a thread of its own while the caller
goes on (on the caller's when there is one thread or it has too few rows) and gives its
value, or raises its error, when asked; the compiled correction, Newton projection and
self-clearance give the same numbers bitwise whatever the threads their rows are split
over."""

from __future__ import annotations

import dataclasses
import threading

import numpy as np
import pytest

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.collision.scene import Scene
from service.pipeline.correction import correct
from service.pipeline.fibre import project, unit_tangent
from service.pipeline.rows import MIN_ASIDE_ROWS, MIN_CHUNK_ROWS, Aside, chunks, over_rows
from service.pipeline.run import fibre_of
from service.pipeline.targets import Target


@pytest.mark.parametrize(
    ("rows", "threads"),
    [(0, 2), (1, 4), (MIN_CHUNK_ROWS * 2 - 1, 2), (1000, 2), (1000, 3), (1001, 16)],
)
def test_the_chunks_cover_the_rows_in_order(rows: int, threads: int) -> None:
    parts = chunks(rows, threads)
    covered = np.concatenate([np.arange(rows)[part] for part in parts])
    assert covered.tolist() == list(range(rows))
    assert 1 <= len(parts) <= threads
    if len(parts) > 1:
        assert min(part.stop - part.start for part in parts) >= MIN_CHUNK_ROWS
    assert len(parts) == max(1, min(threads, rows // MIN_CHUNK_ROWS))


def test_a_call_over_rows_runs_on_helper_threads_in_order() -> None:
    seen: list[str] = []

    def call(part: slice) -> tuple[int, int]:
        seen.append(threading.current_thread().name)
        return part.start, part.stop

    result = over_rows(call, 1000, 3)
    assert result == [(part.start, part.stop) for part in chunks(1000, 3)]
    assert threading.current_thread().name in seen
    assert sum(name.startswith("smm-rows") for name in seen) == 2
    assert over_rows(call, 10, 3) == [(0, 10)]  # too few rows: the caller's thread alone


def test_work_set_aside_runs_beside_the_caller_and_gives_its_value() -> None:
    started, release = threading.Event(), threading.Event()

    def call() -> str:
        started.set()
        assert release.wait(10.0)  # only returns once the caller has gone on past it
        return threading.current_thread().name

    aside = Aside(call, threads=2, rows=MIN_ASIDE_ROWS)
    assert started.wait(10.0)
    release.set()
    assert aside.result().startswith("smm-aside")
    # One thread, or too few rows to repay the hand-off: at once, on the caller's.
    here = threading.current_thread().name
    assert Aside(lambda: threading.current_thread().name, 1, MIN_ASIDE_ROWS).result() == here
    assert Aside(lambda: threading.current_thread().name, 2, MIN_ASIDE_ROWS - 1).result() == here


@pytest.mark.parametrize("threads", [1, 2])
def test_an_error_set_aside_is_raised_when_its_value_is_asked(threads: int) -> None:
    def call() -> int:
        raise ValueError("no value")

    if threads == 1:
        with pytest.raises(ValueError, match="no value"):
            Aside(call, threads, MIN_ASIDE_ROWS)
        return
    aside = Aside(call, threads, MIN_ASIDE_ROWS)
    with pytest.raises(ValueError, match="no value"):
        aside.result()


@pytest.fixture(scope="module")
def iiwa14_pose() -> ServedModel:
    return load_model(REPO_MODELS_DIR / "iiwa14-pose", threads=1)


@pytest.mark.parametrize("threads", [2, 3])
def test_the_compiled_steps_are_the_same_on_any_threads(
    iiwa14_pose: ServedModel, threads: int
) -> None:
    model = iiwa14_pose
    limits, task, defaults = model.limits, model.manifest.task, model.manifest.defaults
    rng = np.random.default_rng(8)
    q_target = rng.uniform(limits.lower_rad, limits.upper_rad)
    fk = model.kinematics(q_target[None])
    target = Target(
        position_m=fk.position_m[0], rotation=fk.rotation[0], condition=np.zeros(1, np.float32)
    )
    q = q_target + rng.normal(0, 0.05, (1000, limits.count))
    one = correct(q, target, task, model.kinematics, 10, defaults.damping, limits, threads=1)
    many = correct(q, target, task, model.kinematics, 10, defaults.damping, limits, threads=threads)
    for field in ("q_rad", "position_error_m", "orientation_error_rad", "jacobian"):
        np.testing.assert_array_equal(getattr(one, field), getattr(many, field))
    fibre = fibre_of(model, target)
    split = dataclasses.replace(fibre, threads=threads)
    tangent = unit_tangent(fibre.residual(q)[1])
    locked = rng.random(q.shape) < 0.2  # (B, n) each row its own locked joints
    cases = (
        {"iterations": 3, "tangent": tangent},
        {"iterations": 4, "until": 1e-10},
        {"iterations": 3, "locked": locked},
    )
    for case in cases:
        a, b = project(fibre, q, **case), project(split, q, **case)
        for x, y in ((a.q_rad, b.q_rad), (a.error, b.error), (a.jacobian, b.jacobian)):
            np.testing.assert_array_equal(x, y)


def test_the_self_clearance_is_the_same_on_any_threads(iiwa14_pose: ServedModel) -> None:
    model = iiwa14_pose
    rng = np.random.default_rng(9)
    q = rng.uniform(model.limits.lower_rad, model.limits.upper_rad, (700, model.limits.count))
    checks = [
        CollisionCheck(model.robot_spheres, Scene(), check_self=True, margin_m=0.01, threads=t)
        for t in (1, 2, 4)
    ]
    one, *many = (check.clearance_m(q) for check in checks)
    assert np.isfinite(one).all() and (one < 0.01).any()  # some rows go to the refined pass
    for other in many:
        np.testing.assert_array_equal(one, other)
