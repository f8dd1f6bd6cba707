"""chain, refine, cut and densify: the trace's phases after the walk, compiled or on flat
arrays, give the Python loops' answers (tests/service/pipeline/connect/trace_reference.py)
to the bit on traced iiwa14 pose, Panda pose and planar 3R fibres: the same curves from the
fronts (rows in order, unwrapped points, closedness), the same curves refined near the
limits, the same runs (points, rows, closedness, the outside point at each end) and the same
pieces (every path point, its error, closedness); and on a closed curve that leaves the
limits and comes back twice (turned to start outside, so no run wraps round). A curve wholly
inside is one run, one wholly outside none; malformed curve bounds are refused. Fronts
that reached fewer points than there are fronts chain as the loops chain them, and the
compiled chaining writes nothing past the buffers it is given. The refinement's rounds on
kinematics that are no serial chain (numpy) add the compiled rounds' points, and refine the
run ends onto the limits as the compiled kernel does."""

from __future__ import annotations

import numpy as np
import pytest

from service.manifest import REPO_MODELS_DIR
from service.models.chain import SerialChainKinematics
from service.models.registry import ServedModel, load_model
from service.pipeline import _native, native  # type: ignore[attr-defined]
from service.pipeline.connect.trace import TraceSettings, walk
from service.pipeline.connect.trace.cut import Runs, cut_by_limits, refine_near_limits, window_low
from service.pipeline.connect.trace.densify import densify, limit_points
from service.pipeline.connect.trace.points import Curves, Evaluated
from service.pipeline.connect.trace.seeds import spread_seeds
from service.pipeline.deadline import NO_DEADLINE
from service.pipeline.fibre import Fibre, evaluate, project, unit_tangent
from service.pipeline.joint_space import JointLimits
from tests.service.pipeline.connect import trace_reference as reference
from tests.service.pipeline.fibre_support import pose_fibre
from tests.support.numpy_kernels import NumpyStepsKinematics
from training.evaluate.targets import uniform_configurations

SETTINGS = TraceSettings(
    step_rad=0.15, max_steps=200, seed_spacing_rad=1.0, path_spacing_rad=0.05
)  # the bundled models' defaults


def traced(
    fibre: Fibre, q_on_fibre: np.ndarray, monkeypatch: pytest.MonkeyPatch
) -> tuple[Evaluated, Curves, list[reference.Curve]]:
    """trace_fibre's phases up to the refinement: the walked curves, and the reference's
    chaining of the same fronts."""
    start = evaluate(fibre, spread_seeds(q_on_fibre, SETTINGS.seed_spacing_rad))
    tangent = unit_tangent(start.jacobian)
    seeds = Evaluated.of(start, tangent).take(np.all(np.isfinite(tangent), axis=1))
    calls = []
    chain = walk.chain_fronts

    def recorded(
        evaluated: Evaluated, num_seeds: int, by_front: np.ndarray, partner: np.ndarray
    ) -> Curves:
        calls.append((num_seeds, by_front, partner))
        return chain(evaluated, num_seeds, by_front, partner)

    monkeypatch.setattr(walk, "chain_fronts", recorded)
    evaluated, curves, _ = walk.walk_fronts(fibre, seeds, SETTINGS, NO_DEADLINE)
    monkeypatch.undo()
    ((num_seeds, by_front, partner),) = calls
    order = np.argsort(by_front, kind="stable")
    bounds = np.searchsorted(by_front[order], np.arange(2 * num_seeds + 1))
    fronts = [num_seeds + order[bounds[f] : bounds[f + 1]] for f in range(2 * num_seeds)]
    return evaluated, curves, reference.chain(evaluated, num_seeds, fronts, partner)


def assert_same_curves(curves: Curves, expected: list[reference.Curve]) -> None:
    assert len(curves) == len(expected)
    for c, want in enumerate(expected):
        rows = slice(curves.first[c], curves.first[c + 1])
        np.testing.assert_array_equal(curves.rows[rows], want.rows)
        np.testing.assert_array_equal(curves.points[rows], want.points)
        assert curves.closed[c] == want.closed


def assert_same_runs(runs: Runs, expected: list[reference.Run]) -> None:
    assert len(runs) == len(expected)
    for r, run in enumerate(expected):
        rows = slice(runs.first[r], runs.first[r + 1])
        np.testing.assert_array_equal(runs.points[rows], run.points)
        np.testing.assert_array_equal(runs.rows[rows], run.rows)
        assert runs.closed[r] == run.closed
        for side, exit_rad in enumerate((run.start_exit, run.end_exit)):
            assert runs.has_exit[r, side] == (exit_rad is not None)
            if exit_rad is not None:
                np.testing.assert_array_equal(runs.exits[r, side], exit_rad)


@pytest.mark.parametrize("model_id", ["iiwa14-pose", "panda-pose", "planar3r-position"])
def test_curves_runs_and_pieces_are_the_python_loops_answers(
    model_id: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    model: ServedModel = load_model(REPO_MODELS_DIR / model_id, threads=1)
    limits = JointLimits.of(model.manifest.joints)
    checked_pieces = refined_curves = 0
    for seed, q_target in enumerate(uniform_configurations(limits, 6, seed=41)):
        fibre = pose_fibre(model, q_target)
        near = q_target + np.random.default_rng(seed).normal(0.0, 0.5, (200, len(q_target)))
        on_fibre = project(fibre, near, 20)
        evaluated, curves, chained = traced(
            fibre, on_fibre.q_rad[on_fibre.error_norm < 1e-9], monkeypatch
        )
        assert_same_curves(curves, chained)
        refined_evaluated, curves = refine_near_limits(fibre, evaluated, curves, limits, SETTINGS)
        expected_evaluated, loops = reference.refine_near_limits(
            fibre, evaluated, chained, limits, SETTINGS
        )
        for ours, theirs in zip(
            (refined_evaluated.q_rad, refined_evaluated.error, refined_evaluated.tangent),
            (expected_evaluated.q_rad, expected_evaluated.error, expected_evaluated.tangent),
            strict=True,
        ):
            np.testing.assert_array_equal(ours, theirs)
        assert_same_curves(curves, loops)
        refined_curves += len(refined_evaluated) > len(evaluated)
        evaluated = refined_evaluated
        runs = cut_by_limits(curves, limits)
        expected_runs = reference.cut_by_limits(loops, limits)
        assert_same_runs(runs, expected_runs)
        pieces = densify(fibre, evaluated, runs, limits, SETTINGS)
        expected = reference.densify(fibre, evaluated, expected_runs, limits, SETTINGS)
        assert len(pieces) == len(expected)
        for piece, want in zip(pieces, expected, strict=True):
            np.testing.assert_array_equal(piece.path_rad, want.path_rad)
            np.testing.assert_array_equal(piece.error, want.error)
            assert piece.closed == want.closed
        checked_pieces += len(pieces)
    assert checked_pieces >= 6


def traced_both_ways(
    model: ServedModel, q_target: np.ndarray, seed: int, monkeypatch: pytest.MonkeyPatch
) -> tuple[Fibre, Fibre, Evaluated, Curves]:
    """The fibre q_target reaches, on the model's serial chain and on the same kinematics
    behind a plain callable (numpy steps), and the curves walked from points near q_target
    on the first."""
    fibre = pose_fibre(model, q_target)
    assert isinstance(model.kinematics, SerialChainKinematics)
    through = Fibre(fibre.target, fibre.task, NumpyStepsKinematics(model.kinematics), 1e-3)
    near = q_target + np.random.default_rng(seed).normal(0.0, 0.5, (200, len(q_target)))
    on_fibre = project(fibre, near, 20)
    evaluated, curves, _ = traced(fibre, on_fibre.q_rad[on_fibre.error_norm < 1e-9], monkeypatch)
    return fibre, through, evaluated, curves


@pytest.mark.parametrize("model_id", ["iiwa14-pose", "panda-pose"])
def test_the_refinement_on_any_kinematics_adds_the_compiled_rounds_points(
    model_id: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The refinement's rounds run compiled on a serial chain (`native.refine_round`) and
    in numpy on other kinematics: on the same traced curves the two add the same points
    (to 1e-12: the numpy Newton's rounding) with the same curves, and points are added."""
    model: ServedModel = load_model(REPO_MODELS_DIR / model_id, threads=1)
    limits = JointLimits.of(model.manifest.joints)
    refined = 0
    for seed, q_target in enumerate(uniform_configurations(limits, 6, seed=41)):
        fibre, through, evaluated, curves = traced_both_ways(model, q_target, seed, monkeypatch)
        compiled, compiled_curves = refine_near_limits(fibre, evaluated, curves, limits, SETTINGS)
        numpy_, numpy_curves = refine_near_limits(through, evaluated, curves, limits, SETTINGS)
        assert len(compiled) == len(numpy_)
        for ours, theirs in zip(
            (compiled.q_rad, compiled.error, compiled.jacobian, compiled.tangent),
            (numpy_.q_rad, numpy_.error, numpy_.jacobian, numpy_.tangent),
            strict=True,
        ):
            np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(compiled_curves.rows, numpy_curves.rows)
        np.testing.assert_array_equal(compiled_curves.first, numpy_curves.first)
        refined += len(compiled) > len(evaluated)
    assert refined >= 1


@pytest.mark.parametrize("model_id", ["iiwa14-pose", "panda-pose"])
def test_run_ends_on_any_kinematics_are_the_compiled_limit_points(
    model_id: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each run end refined onto its limit runs compiled on a serial chain
    (`native.limit_points`) and in numpy on other kinematics: on the same runs the two give
    the same points (to 1e-12: the numpy Newton's rounding), on their limits, and the same
    choice of ends; some ends are refined."""
    model: ServedModel = load_model(REPO_MODELS_DIR / model_id, threads=1)
    limits = JointLimits.of(model.manifest.joints)
    low = window_low(limits)
    refined = 0
    for seed, q_target in enumerate(uniform_configurations(limits, 6, seed=41)):
        fibre, through, evaluated, curves = traced_both_ways(model, q_target, seed, monkeypatch)
        evaluated, curves = refine_near_limits(fibre, evaluated, curves, limits, SETTINGS)
        runs = cut_by_limits(curves, limits)
        ours = limit_points(fibre, runs, evaluated, limits, low, SETTINGS)
        theirs = limit_points(through, runs, evaluated, limits, low, SETTINGS)
        np.testing.assert_array_equal(ours[2], theirs[2])  # the same ends refined
        for x, y in (
            (ours[0].q_rad, theirs[0].q_rad), (ours[0].error, theirs[0].error),
            (ours[0].jacobian, theirs[0].jacobian), (ours[0].tangent, theirs[0].tangent),
            (ours[1], theirs[1]),
        ):  # fmt: skip
            np.testing.assert_allclose(x, y, rtol=0, atol=1e-12)
        assert np.all(limits.contains(ours[1]))
        on_limit = (ours[1] == limits.lower_rad) | (ours[1] == limits.upper_rad)  # (L, n)
        assert np.all(on_limit.any(axis=1))  # each held exactly on a limit
        refined += len(ours[1])
    assert refined >= 1


def circle_curve(turns_rad: float = 0.0) -> tuple[Curves, JointLimits]:
    """A closed curve of 40 points round a circle of radius 1 in two joints, joint 0
    limited to [-0.5, 0.5] (the curve leaves and comes back twice), joint 1 periodic."""
    theta = np.linspace(0.0, 2 * np.pi, 40, endpoint=False)
    q = np.stack([np.cos(theta), np.sin(theta) + turns_rad], axis=1)
    evaluated = Evaluated(q, np.zeros((40, 1)), np.zeros((40, 1, 2)), np.zeros((40, 2)))
    limits = JointLimits(
        lower_rad=np.array([-0.5, -np.pi]),
        upper_rad=np.array([0.5, np.pi]),
        periodic=np.array([False, True]),
    )
    rows = np.roll(np.arange(40), 3)
    return Curves.of(evaluated, rows, np.array([0, 40]), np.array([True])), limits


@pytest.mark.parametrize("turns_rad", [0.0, 3.0])
def test_a_closed_curve_leaving_the_limits_is_turned_to_start_outside(turns_rad: float) -> None:
    loop, limits = circle_curve(turns_rad)
    runs = cut_by_limits(loop, limits)
    assert_same_runs(runs, reference.cut_by_limits(reference.curve_list(loop), limits))
    assert len(runs) == 2 and not runs.closed.any() and runs.has_exit.all()
    inside = cut_by_limits(loop, JointLimits(
        lower_rad=np.array([-2.0, -np.pi]), upper_rad=np.array([2.0, np.pi]),
        periodic=np.array([False, True]),
    ))  # fmt: skip
    assert len(inside) == 1 and inside.closed[0] and not inside.has_exit.any()
    np.testing.assert_array_equal(inside.points, loop.points)
    outside = cut_by_limits(loop, JointLimits(
        lower_rad=np.array([1.5, -np.pi]), upper_rad=np.array([2.0, np.pi]),
        periodic=np.array([False, True]),
    ))  # fmt: skip
    assert len(outside) == 0 and len(outside.points) == 0


def test_curve_bounds_that_do_not_cover_the_points_are_refused() -> None:
    loop, limits = circle_curve()
    with pytest.raises(ValueError, match="first must run from 0"):
        native.cut_runs(
            loop.points, loop.rows, np.array([0, 30]), np.array([True]), np.zeros(2),
            limits.lower_rad, limits.upper_rad, limits.periodic,
        )  # fmt: skip
    evaluated = Evaluated(loop.points, np.zeros((40, 1)), np.zeros((40, 1, 2)), np.zeros((40, 2)))
    with pytest.raises(ValueError, match="first must run from 0"):
        native.curve_steps(
            evaluated.q_rad, evaluated.tangent, loop.points, loop.rows, np.array([0, 30]),
            np.array([True]),
        )  # fmt: skip
    with pytest.raises(ValueError, match="rows must index the 40 evaluated points"):
        native.curve_steps(
            evaluated.q_rad, evaluated.tangent, loop.points, loop.rows + 1, loop.first,
            loop.closed,
        )  # fmt: skip


# Fronts that reached fewer points than there are fronts: 3 seeds, 6 fronts and 2 reached
# points (fronts 0 and 3, which met), as at a near-singular target where most fronts fail
# on their first step (a Panda pose one did).
FEW_SEEDS = 3
FEW_BY_FRONT = np.array([0, 3])  # (reached,) the front that reached each point
FEW_PARTNER = np.array([3, -1, -1, 0, -1, -1])  # (fronts,)


def test_fronts_that_reached_fewer_points_than_fronts_chain_as_the_loops_chain_them() -> None:
    """Seeds whose fronts mostly reached nothing: the compiled chaining gives the Python
    loops' curves (every seed on one, the two that met joined through their fronts), and it
    writes nothing past the buffers it is given at the sizes `native.chain_fronts` gives
    them: its 2 S fronts may outnumber its T points, so per-front state in a scratch of T
    rows would be written past its end, into the heap of the process answering the target."""
    seeds, by_front, partner = FEW_SEEDS, FEW_BY_FRONT, FEW_PARTNER
    total, n = seeds + len(by_front), 7
    q = np.random.default_rng(12).uniform(-3.0, 3.0, (total, n))
    evaluated = Evaluated(q, np.zeros((total, 6)), np.zeros((total, 6, n)), np.zeros((total, n)))
    fronts = [seeds + np.flatnonzero(by_front == f) for f in range(2 * seeds)]
    rows, first, closed = native.chain_fronts(q, seeds, by_front, partner)
    assert_same_curves(
        Curves.of(evaluated, rows, first, closed),
        reference.chain(evaluated, seeds, fronts, partner),
    )
    assert len(first) - 1 == 2  # seeds 0 and 1 joined, seed 2 alone

    guard = 4  # sentinel entries after every buffer the kernel writes
    sizes = {  # what native.chain_fronts allocates: fronts + 1, reached, seeds, fronts, total ...
        "front_first": (2 * seeds + 1, np.int64), "front_rows": (len(by_front), np.int64),
        "visited": (seeds, np.uint8), "overlap": (2 * seeds, np.uint8),
        "ahead": (total, np.int64), "behind": (total, np.int64), "rows": (total, np.int64),
        "first": (seeds + 1, np.int64), "closed": (seeds, np.uint8),
    }  # fmt: skip
    padded = {name: np.full(size + guard, 77, dtype) for name, (size, dtype) in sizes.items()}
    _native.chain_fronts(
        q, total, n, seeds, by_front, partner,
        *(padded[name][: sizes[name][0]] for name in sizes),
    )  # fmt: skip
    for name, (size, _) in sizes.items():
        assert np.all(padded[name][size:] == 77), f"{name}: written past its {size} entries"
