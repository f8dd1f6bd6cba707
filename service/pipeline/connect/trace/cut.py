"""Phase 4: curves refined where a step may pass through the joint limits unseen, then
cut by the limits into runs of consecutive points inside them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np

from service.pipeline import native
from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.connect.trace.points import (
    Curves,
    Evaluated,
    TraceSettings,
    torus_difference,
)
from service.pipeline.fibre import Fibre, project, unit_tangent
from service.pipeline.joint_space import TWO_PI, JointLimits
from service.pipeline.native import along, hermite
from service.pipeline.targets import kernel_orientation
from service.pipeline.types import ChainKinematics

# Bordered Newton steps from each piece's Hermite guess onto the fibre (rows within the
# path error stop early).
PROJECTION_ITERATIONS = 2


def window_low(limits: JointLimits) -> FloatArray:
    """Lower end (n,) of the 2 pi window each joint angle is read in: the limits inside it."""
    centre = np.where(limits.periodic, 0.0, 0.5 * (limits.lower_rad + limits.upper_rad))
    return centre - np.pi


def to_window(q_rad: FloatArray, window_low: FloatArray) -> FloatArray:
    """Angles (..., n) mapped into [window_low, window_low + 2 pi)."""
    return window_low + np.mod(q_rad - window_low, TWO_PI)


def refine_near_limits(
    fibre: Fibre,
    evaluated: Evaluated,
    curves: Curves,
    limits: JointLimits,
    settings: TraceSettings,
    rounds: int = 3,
    pieces: int = 4,
) -> tuple[Evaluated, Curves]:
    """Curves with points added where a step may pass through the limits unseen.

    A component shorter than a step can lie between two traced points that are both
    outside the limits. Where the chord of a step, widened by how far a curve bends in
    a step, meets the limit box, the step is split into `pieces` projected points (from
    the Hermite curve through its ends); a few rounds, each looking again only at the
    pieces of the steps the last one split, find components down to about
    h / pieces**rounds long. The evaluated points come back with the added ones. On a
    serial chain each round is one compiled call (`native.refine_round`), in place of
    the numpy round's few dozen small array calls.
    """
    low = window_low(limits)
    steps = Steps.of(evaluated, curves)
    rounds_of = _numpy_rounds if fibre.chain is None else _compiled_rounds
    added, added_loop, added_key = rounds_of(fibre, steps, limits, low, settings, rounds, pieces)
    count_added = sum(len(a) for a in added)
    if not added:
        return evaluated, curves
    # The added points into their curves, in order of their places along them.
    before = len(evaluated)
    evaluated = evaluated.extended(*added)
    size = np.diff(curves.first)  # (C,)
    curve_of = np.repeat(np.arange(len(curves)), size)  # (P,)
    place = np.arange(len(curve_of)) - curves.first[curve_of]  # (P,) index in its curve
    loop_of = np.concatenate(added_loop)
    order = np.lexsort(
        (np.concatenate([place, np.concatenate(added_key)]), np.concatenate([curve_of, loop_of]))
    )
    rows = np.concatenate([curves.rows, before + np.arange(count_added)])[order]
    first = np.concatenate([[0], np.cumsum(size + np.bincount(loop_of, minlength=len(size)))])
    return evaluated, Curves.of(evaluated, rows, first, curves.closed)


# Each round's added points, their curves and their places along them.
Added = tuple[list[Evaluated], list[IntArray], list[FloatArray]]


def _compiled_rounds(
    fibre: Fibre,
    steps: Steps,
    limits: JointLimits,
    low: FloatArray,  # (n,) window_low
    settings: TraceSettings,
    rounds: int,
    pieces: int,
) -> Added:
    """The rounds of `refine_near_limits` on a serial chain, each one compiled call
    (`native.refine_round`: the numpy rounds' numbers)."""
    chain = cast(ChainKinematics, fibre.chain)
    target = fibre.target
    rotation = kernel_orientation(fibre.task, target)
    added: list[Evaluated] = []
    added_loop: list[IntArray] = []
    added_key: list[FloatArray] = []
    trace_steps: native.TraceSteps = steps
    for _ in range(rounds):
        refined = native.refine_round(
            chain.fixed, chain.tip, fibre.task.position_axes, target.position_m, rotation,
            trace_steps, low, limits.lower_rad, limits.upper_rad, limits.periodic, pieces,
            PROJECTION_ITERATIONS, settings.path_error, fibre.damping,
        )  # fmt: skip
        if not len(refined.loop):  # no step near the limits, or none split
            break
        added.append(Evaluated(refined.q_rad, refined.error, refined.jacobian, refined.tangent))
        added_loop.append(refined.loop)
        added_key.append(refined.key)
        trace_steps = refined.steps
    return added, added_loop, added_key


def _numpy_rounds(
    fibre: Fibre,
    steps: Steps,
    limits: JointLimits,
    low: FloatArray,  # (n,) window_low
    settings: TraceSettings,
    rounds: int,
    pieces: int,
) -> Added:
    """The rounds of `refine_near_limits` on any kinematics, in numpy."""
    lower_rad, upper_rad, periodic = limits.lower_rad, limits.upper_rad, limits.periodic
    added: list[Evaluated] = []
    added_loop: list[IntArray] = []
    added_key: list[FloatArray] = []
    fraction = np.arange(1, pieces) / pieces  # (p - 1,)
    for _ in range(rounds):
        # Both ends outside, the chord through the box widened by a margin of L / 4 per
        # step (a curve bends off its chord by ~kappa L^2 / 8), by the slab test (compiled).
        steps = steps.take(
            native.steps_near_limits(steps.start, steps.delta, low, lower_rad, upper_rad, periodic)
        )
        if not len(steps.loop):
            break
        count = len(steps.loop)
        guess, direction = hermite(
            np.repeat(steps.start, pieces - 1, axis=0),
            np.repeat(steps.start_tangent, pieces - 1, axis=0),
            np.repeat(steps.start + steps.delta, pieces - 1, axis=0),
            np.repeat(steps.end_tangent, pieces - 1, axis=0),
            np.tile(fraction, count),
        )  # (C (p - 1), n)
        projected = project(
            fibre, guess, PROJECTION_ITERATIONS, tangent=direction, until=settings.path_error
        )
        ok = np.all((projected.error_norm < 1e-6).reshape(count, pieces - 1), axis=1)  # (C,)
        if not ok.any():
            break
        keep = np.repeat(ok, pieces - 1)
        new = Evaluated.of(projected, unit_tangent(projected.jacobian, previous=direction))
        added.append(new.take(keep))
        steps = steps.take(ok)
        added_loop.append(np.repeat(steps.loop, pieces - 1))
        added_key.append((steps.key[:, None] + steps.span[:, None] * fraction).ravel())
        steps = steps.split(added[-1].q_rad, added[-1].tangent)
    return added, added_loop, added_key


@dataclass(frozen=True)
class Steps(native.TraceSteps):
    """Steps of traced curves between evaluated points (C of them), as the refinement
    looks at them: unwrapped start and chord, tangents along the chord at both ends (the
    fields of `native.TraceSteps`, which the compiled rounds take as they are)."""

    @classmethod
    def of(cls, evaluated: Evaluated, curves: Curves) -> Steps:
        """Every step of every curve (the closing step of a closed one included), compiled
        (`native.curve_steps`)."""
        steps = native.curve_steps(
            evaluated.q_rad, evaluated.tangent, curves.points, curves.rows, curves.first,
            curves.closed,
        )  # fmt: skip
        return cls(**vars(steps))

    def take(self, rows: BoolArray) -> Steps:
        return Steps(
            self.loop[rows], self.key[rows], self.span[rows], self.start[rows],
            self.delta[rows], self.start_tangent[rows], self.end_tangent[rows],
        )  # fmt: skip

    def split(self, new_q_rad: FloatArray, new_tangent: FloatArray) -> Steps:
        """Each step as its `pieces` steps through its new points (C (pieces - 1), n) in
        order, step after step."""
        count = len(self.loop)
        n = self.start.shape[1]
        q = new_q_rad.reshape(count, -1, n)  # (C, p - 1, n)
        pieces = q.shape[1] + 1
        end = self.start + self.delta
        # The new points in the step's unwrapped coordinates: each moved little from its guess.
        q = self.start[:, None, :] + torus_difference(q, self.start[:, None, :])
        nodes = np.concatenate([self.start[:, None], q, end[:, None]], axis=1)  # (C, p + 1, n)
        tangents = np.concatenate(
            [
                self.start_tangent[:, None],
                new_tangent.reshape(count, -1, n),
                self.end_tangent[:, None],
            ],
            axis=1,
        )  # (C, p + 1, n)
        delta = np.diff(nodes, axis=1).reshape(-1, n)  # (C p, n)
        span = np.repeat(self.span / pieces, pieces)
        return Steps(
            loop=np.repeat(self.loop, pieces),
            key=np.repeat(self.key, pieces) + span * np.tile(np.arange(pieces), count),
            span=span,
            start=nodes[:, :-1].reshape(-1, n),
            delta=delta,
            start_tangent=along(tangents[:, :-1].reshape(delta.shape), delta),
            end_tangent=along(tangents[:, 1:].reshape(delta.shape), delta),
        )


@dataclass(frozen=True)
class Runs:
    """The runs of consecutive traced points inside the limits (R of them), run after run."""

    points: FloatArray  # (P, n) unwrapped along each run
    rows: IntArray  # (P,) their evaluated rows
    first: IntArray  # (R + 1,) run r is [first[r], first[r + 1])
    closed: BoolArray  # (R,) a whole curve inside the limits
    exits: FloatArray  # (R, 2, n) the outside point before the run and after it ...
    has_exit: BoolArray  # (R, 2) ... where there is one (not at an open curve's own end)

    def __len__(self) -> int:
        return len(self.closed)


def cut_by_limits(curves: Curves, limits: JointLimits) -> Runs:
    """The runs of consecutive points of each curve that lie inside the limits: a curve
    inside all along is one run; a closed curve that leaves them is turned to start
    outside (its points past the start moved on by its turns, so the run stays
    continuous), so that no run wraps round; compiled (`native.cut_runs`)."""
    cut = native.cut_runs(
        curves.points, curves.rows, curves.first, curves.closed, window_low(limits),
        limits.lower_rad, limits.upper_rad, limits.periodic,
    )  # fmt: skip
    return Runs(*cut)
