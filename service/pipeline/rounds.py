"""Stages 2-4 for r = 1 in rounds: draw until a round finds no curve not already traced.

For a 1-D fibre the connect stage traces every curve whole from one sample on it, so the
samples only need to put one on every component; more samples repeat what the trace
recovers. With the model's `sampler.round_samples`, stage 2 draws that many at a time (one
generator for every round, seeded by the query, so an answer depends on its seed alone),
each round is corrected and accepted, and the curves through its accepted samples that
no traced curve passes are traced (connect.trace_curves, connect.extend_curves, on the
kinematic space: collisions cut the curves later), and so are those through its samples
within tolerance but outside the limits that no traced point comes near (a curve can
leave the limits and come back where no sample fell, as the one-shot trace from every
sample within tolerance finds). Drawing stops after a round whose samples within
tolerance all lie on curves already traced, or once num_samples are drawn.
The connect stage then starts from these curves and the path each accepted sample lies
on, found round by round (found again for every sample only where a later round traced a
new path, which may pass nearer to an earlier sample).

The rule's miss rate, a component no round put a sample on, is measured against the exact
SMMs by the judge (training/evaluate/judge.py), which decides the model's round size.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass

import numpy as np

from service.manifest import ConnectivitySpec
from service.pipeline.arrays import FloatArray, IntArray
from service.pipeline.connect import (
    Extension,
    TracedCurves,
    extend_curves,
    on_curves,
    trace_curves,
)
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.space import FibreSpace
from service.pipeline.types import Acceptance, Correction, Stage


@dataclass(frozen=True)
class Drawn:
    """Every round's samples, corrected and accepted, in drawing order, and the curves
    traced through them."""

    correction: Correction  # (N,) over the rounds drawn
    acceptance: Acceptance  # (N,)
    traced: Extension  # the curves, and the path each sample on the fibre lies on (K,)
    rounds: int


def draw_in_rounds(
    space: FibreSpace,
    num_samples: int,  # at most this many in all
    round_samples: int,
    draw: Callable[[int], FloatArray],  # k -> (k, n) the next k samples of the query's stream
    correct: Callable[[FloatArray], Correction],  # stage 3 on one round's samples
    spec: ConnectivitySpec,
    stage: Callable[[Stage], AbstractContextManager[None]],  # times the named stage
    deadline: Deadline = NO_DEADLINE,
) -> Drawn:
    """Rounds of `round_samples` (the last one smaller when num_samples runs out) until one
    whose accepted samples all lie on the curves traced from the rounds before."""
    kinematic = space.kinematic()
    corrections: list[Correction] = []
    acceptances: list[Acceptance] = []
    curves: TracedCurves | None = None
    owners: list[IntArray] = []  # each round's samples on the fibre: the path each lies on
    owned_paths: list[int] = []  # how many paths there were when each round's was found
    drawn = 0
    while drawn < num_samples:
        size = min(round_samples, num_samples - drawn)
        with stage("sample"):
            q_sampled_rad = draw(size)  # (size, n)
        with stage("correct"):
            correction = correct(q_sampled_rad)
        with stage("accept"):
            acceptance = space.accept(correction)
        corrections.append(correction)
        acceptances.append(acceptance)
        drawn += size
        q_accepted = correction.q_rad[acceptance.on_fibre]  # (K, n) collisions aside
        first = curves is None
        with stage("connect"):
            if curves is None:
                q_within = correction.q_rad[acceptance.within_tolerance]
                extension = trace_curves(kinematic, q_within, q_accepted, spec, deadline)
            else:
                outside = acceptance.within_tolerance & ~acceptance.within_limits
                q_outside = correction.q_rad[outside]  # (O, n) their curves may enter the limits
                extension = extend_curves(curves, kinematic, q_accepted, spec, deadline, q_outside)
            curves = extension.curves
            owners.append(extension.owner)
            owned_paths.append(len(curves.paths))
        if not first and (len(q_accepted) or len(q_outside)) and not extension.strays:
            break
    assert curves is not None, "num_samples >= 1 draws a round"
    correction = _concatenate_corrections(corrections)
    on_fibre = np.concatenate([a.on_fibre for a in acceptances])
    traced = Extension(curves, 0, np.concatenate(owners))  # (K,) paths of the samples on the fibre
    if min(owned_paths) < len(curves.paths):  # a later round's path may pass nearer
        with stage("connect"):
            traced = on_curves(curves, kinematic.limits, correction.q_rad[on_fibre], spec)
    return Drawn(
        correction=correction,
        acceptance=Acceptance(
            within_tolerance=np.concatenate([a.within_tolerance for a in acceptances]),
            within_limits=np.concatenate([a.within_limits for a in acceptances]),
            collision_free=np.concatenate([a.collision_free for a in acceptances]),
            clearance_m=_concatenate_clearances(acceptances),
        ),
        traced=traced,
        rounds=len(corrections),
    )


def _concatenate_clearances(acceptances: list[Acceptance]) -> FloatArray | None:
    """The rounds' clearances in one array; None when collisions are not checked (every
    round of a query checks them or none does)."""
    measured = [a.clearance_m for a in acceptances if a.clearance_m is not None]
    if not measured:
        return None
    assert len(measured) == len(acceptances), "every round checks collisions or none"
    return np.concatenate(measured)


def _concatenate_corrections(corrections: list[Correction]) -> Correction:
    return Correction(
        q_rad=np.concatenate([c.q_rad for c in corrections]),
        position_error_m=np.concatenate([c.position_error_m for c in corrections]),
        orientation_error_rad=np.concatenate([c.orientation_error_rad for c in corrections]),
        jacobian=np.concatenate([c.jacobian for c in corrections]),
    )
