"""rows: the chunks cover every row once, in order, none shorter than MIN_CHUNK_ROWS unless
there is only one; a call over rows runs its chunks on helper threads and returns their
results in the chunks' order; work set aside runs on a thread of its own while the caller
goes on (on the caller's when there is one thread or it has too few rows) and gives its
value, or raises its error, when asked; the compiled correction, Newton projection and
self-clearance give the same numbers bitwise whatever the threads their rows are split
over; the compiled row helper takes the first chunk of a split call (and none of an unsplit
one), gives the same numbers to callers racing for it, and starts afresh in a forked
child; a count of what runs in flight counts each caller while its block runs; a call splits
only while its query is the only one being answered (the Python pool's, both row helpers',
the int8 layers'), with the same answer either way; the service sets both helpers' spin
from its settings."""

from __future__ import annotations

import dataclasses
import multiprocessing
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from service.config import Settings
from service.main import create_app
from service.manifest import REPO_MODELS_DIR
from service.models import int8_mlp
from service.models.registry import ServedModel, load_model
from service.pipeline import native
from service.pipeline.arrays import FloatArray
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.collision.scene import Scene
from service.pipeline.correction import compiled_newton, correct
from service.pipeline.fibre import Fibre, project, unit_tangent
from service.pipeline.rows import (
    ANSWERING,
    MIN_ASIDE_ROWS,
    MIN_CHUNK_ROWS,
    Aside,
    InFlight,
    chunks,
    helper_rows,
    over_rows,
)
from service.pipeline.run import fibre_of, run
from service.pipeline.targets import Target
from service.pipeline.types import Query
from training.evaluate.served import orientation_wxyz


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


def test_the_helpers_rows_are_the_first_of_two_chunks() -> None:
    assert helper_rows(1000, 2) == chunks(1000, 2)[0].stop == 500
    assert helper_rows(1001, 16) == 500  # one helper: two chunks at most
    assert helper_rows(1000, 1) == 0  # one thread: every row on the caller's
    assert helper_rows(2 * MIN_CHUNK_ROWS - 1, 2) == 0  # too few rows to split
    assert helper_rows(40, 2, min_rows=8) == 20


def _newton_rows(model: ServedModel, rows: int, seed: int) -> tuple[Fibre, FloatArray]:
    """The fibre of a random iiwa14 pose target and `rows` configurations near it."""
    limits = model.limits
    rng = np.random.default_rng(seed)
    q_target = rng.uniform(limits.lower_rad, limits.upper_rad)
    fk = model.kinematics(q_target[None])
    target = Target(
        position_m=fk.position_m[0], rotation=fk.rotation[0], condition=np.zeros(1, np.float32)
    )
    return fibre_of(model, target), q_target + rng.normal(0, 0.05, (rows, limits.count))


def _newton(fibre: Fibre, q: FloatArray, threads: int) -> tuple[FloatArray, ...]:
    """Six compiled DLS steps from q on `threads` (`native.newton` through the correction)."""
    assert fibre.chain is not None
    error, jacobian = fibre.residual(q)
    return compiled_newton(
        fibre.chain, fibre.target, fibre.task, q, error, jacobian, 6, 1e-3, threads=threads
    )


def test_the_row_helper_takes_the_first_chunk_of_a_split_call(iiwa14_pose: ServedModel) -> None:
    fibre, q = _newton_rows(iiwa14_pose, 1000, seed=10)
    before = native.helper_parts()
    one = _newton(fibre, q, threads=1)
    assert native.helper_parts() == before  # not split: the helper did nothing
    two = _newton(fibre, q, threads=2)
    assert native.helper_parts() == before + 1
    for x, y in zip(one, two, strict=True):
        np.testing.assert_array_equal(x, y)


def test_callers_racing_for_the_row_helper_get_the_same_numbers(
    iiwa14_pose: ServedModel,
) -> None:
    """Two threads split calls at once: the one that finds the helper taken does every row
    itself, and each gets its one-thread numbers."""
    fibre, q = _newton_rows(iiwa14_pose, 600, seed=11)
    expected = _newton(fibre, q, threads=1)
    before = native.helper_parts()

    def calls(_: int) -> bool:
        same = True
        for _ in range(40):
            got = _newton(fibre, q, threads=2)
            same &= all(np.array_equal(x, y) for x, y in zip(expected, got, strict=True))
        return same

    with ThreadPoolExecutor(2) as pool:
        assert all(pool.map(calls, range(2)))
    assert before < native.helper_parts() <= before + 80


def _split_in_child(rows: int, seed: int) -> bool:
    model = load_model(REPO_MODELS_DIR / "iiwa14-pose", threads=1)
    fibre, q = _newton_rows(model, rows, seed)
    one, two = (_newton(fibre, q, threads=t) for t in (1, 2))
    return native.helper_parts() == 1 and all(
        np.array_equal(x, y) for x, y in zip(one, two, strict=True)
    )


def test_a_forked_child_starts_a_row_helper_of_its_own(iiwa14_pose: ServedModel) -> None:
    """The parent's helper thread does not survive fork: the child's first split call
    starts its own instead of waiting on one that is not there."""
    fibre, q = _newton_rows(iiwa14_pose, 600, seed=12)
    _newton(fibre, q, threads=2)  # the parent's helper runs
    with multiprocessing.get_context("fork").Pool(1) as pool:
        assert pool.apply_async(_split_in_child, (600, 12)).get(timeout=120)


def test_the_service_sets_both_row_helpers_spin_from_its_settings() -> None:
    """SMM_ROW_HELPER_SPIN_US reaches the kernels' helper and the int8 layers' helper; a
    spin outside 0 to 1 s is refused."""
    before = native.set_helper_spin(0.001), int8_mlp.set_helper_spin(0.001)
    try:
        create_app(Settings(row_helper_spin_us=250))
        assert native.set_helper_spin(0.001) == pytest.approx(250e-6)
        assert int8_mlp.set_helper_spin(0.001) == pytest.approx(250e-6)
        for wrong in (-1e-6, 1.5):
            with pytest.raises(ValueError, match="0 to 1 s"):
                native.set_helper_spin(wrong)
            with pytest.raises(ValueError, match="0 to 1 s"):
                int8_mlp.set_helper_spin(wrong)
    finally:
        native.set_helper_spin(before[0])
        int8_mlp.set_helper_spin(before[1])


def test_in_flight_counts_each_caller_while_its_block_runs() -> None:
    calls = InFlight()
    with calls.entered() as first:
        with calls.entered() as second:
            assert (first, second, calls.count) == (0, 1, 2)
            assert calls.threads(2) == 1
        with calls.entered() as third:
            assert third == 1
        assert calls.threads(2) == 2  # the caller's own, alone
    with calls.entered() as again:
        assert again == 0
    assert calls.count == 0


def test_a_call_splits_only_while_its_query_is_the_only_one_answered() -> None:
    assert len(over_rows(lambda part: part, 4 * MIN_CHUNK_ROWS, threads=2)) == 2
    assert helper_rows(4 * MIN_CHUNK_ROWS, threads=2) == 2 * MIN_CHUNK_ROWS
    with ANSWERING.entered(), ANSWERING.entered():  # two queries answered at once
        assert over_rows(lambda part: part, 4 * MIN_CHUNK_ROWS, threads=2) == [
            slice(0, 4 * MIN_CHUNK_ROWS)
        ]
        assert helper_rows(4 * MIN_CHUNK_ROWS, threads=2) == 0


def test_a_query_answered_beside_another_hands_no_rows_to_the_helpers() -> None:
    """On a model whose calls split over two threads, a query alone hands parts to both
    row helpers (the compiled kernels' and the int8 layers'); answered while another
    query is, it hands none, and its answer is the same to the bit."""
    model = load_model(REPO_MODELS_DIR / "iiwa14-pose", threads=2)
    q = model.limits.lower_rad + 0.37 * (model.limits.upper_rad - model.limits.lower_rad)
    fk = model.kinematics(q[None])
    query = Query.for_model(
        model.manifest,
        position_m=fk.position_m[0].tolist(),
        orientation_wxyz=orientation_wxyz(fk.rotation[0]),
        num_samples=1000,
        seed=4,
    )

    def parts() -> tuple[int, int]:
        return native.helper_parts(), int8_mlp.helper_parts()

    before = parts()
    alone = run(model, query)
    after_alone = parts()
    assert all(a > b for a, b in zip(after_alone, before, strict=True))
    with ANSWERING.entered():  # another query being answered
        beside = run(model, query)
    assert parts() == after_alone
    assert alone.counts == beside.counts and alone.structure == beside.structure
    assert len(alone.components) == len(beside.components) > 0
    for a, b in zip(alone.components, beside.components, strict=True):
        np.testing.assert_array_equal(a.configurations_rad, b.configurations_rad)
