"""What the trace hands between its phases: the settings, the evaluated points (every
configuration the kinematics was evaluated at, with what it measured there), the curves
as rows of them (flat, curve after curve), and the pieces it returns."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.pipeline import native
from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.fibre import Projection
from service.pipeline.joint_space import wrap_to_pi


@dataclass(frozen=True)
class TraceSettings:
    step_rad: float  # h, the continuation step
    max_steps: int  # per front; a curve longer than fronts x steps x h stays open
    seed_spacing_rad: float  # seeds are at least this far apart (torus metric)
    path_spacing_rad: float  # largest gap between consecutive path points
    corrector_iterations: int = 1  # per continuation step (each costs one evaluation)
    # Newton puts each path point within this |e| (well under any tolerance: a point
    # from a Hermite guess usually gets there in one step, and a second costs little) ...
    path_error: float = 5e-11
    path_iterations: int = 9  # ... in at most this many steps (each costs one evaluation)


@dataclass(frozen=True)
class TracedPiece:
    """One component of the fibre within the limits, as an ordered path."""

    path_rad: FloatArray  # (P, n) in order along the curve, joints inside their limits
    error: FloatArray  # (P, m) task error at each path point
    closed: bool  # the path is a whole loop (its last point joins its first)


@dataclass(frozen=True)
class Trace:
    pieces: list[TracedPiece]
    complete: bool  # every front met another: every curve traced closed
    min_singular_value: float  # over the traced points (inf when nothing was traced)
    reached_rad: FloatArray  # (R, n) every point the fronts reached, inside the limits or not


@dataclass(frozen=True)
class Evaluated:
    """Configurations the kinematics was evaluated at, with what it measured there.

    Every traced point is kept with its error, Jacobian and tangent, so that no later
    step evaluates it again: curves refer to these points by row.
    """

    q_rad: FloatArray  # (T, n) as evaluated (on the torus: any turn of each joint)
    error: FloatArray  # (T, m)
    jacobian: FloatArray  # (T, m, n)
    tangent: FloatArray  # (T, n) unit null vector of the Jacobian, either sign

    @classmethod
    def of(cls, projection: Projection, tangent: FloatArray) -> Evaluated:
        return cls(projection.q_rad, projection.error, projection.jacobian, tangent)

    def __len__(self) -> int:
        return len(self.q_rad)

    def take(self, rows: IntArray | BoolArray) -> Evaluated:
        return Evaluated(
            self.q_rad[rows], self.error[rows], self.jacobian[rows], self.tangent[rows]
        )

    def extended(self, *others: Evaluated) -> Evaluated:
        parts = (self, *others)
        return Evaluated(
            np.concatenate([p.q_rad for p in parts]),
            np.concatenate([p.error for p in parts]),
            np.concatenate([p.jacobian for p in parts]),
            np.concatenate([p.tangent for p in parts]),
        )


@dataclass(frozen=True)
class Curves:
    """Traced curves (C of them), curve after curve: rows of the evaluated points in order
    along each, and those points made continuous (every step the short way round)."""

    rows: IntArray  # (P,)
    points: FloatArray  # (P, n) unwrapped along each curve
    first: IntArray  # (C + 1,) curve c is [first[c], first[c + 1])
    closed: BoolArray  # (C,) the last point joins the first

    def __len__(self) -> int:
        return len(self.closed)

    @classmethod
    def of(cls, evaluated: Evaluated, rows: IntArray, first: IntArray, closed: BoolArray) -> Curves:
        """The curves through `rows` of `evaluated`, unwrapped (`native.unwrap_curves`)."""
        return cls(rows, native.unwrap_curves(evaluated.q_rad, rows, first), first, closed)


def torus_difference(a: FloatArray, b: FloatArray) -> FloatArray:
    return wrap_to_pi(a - b)
