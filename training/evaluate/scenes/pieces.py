"""The exact SMM of a pose cut by coal into its free pieces, and the service's
components matched against them.

Each reference curve (an exact component, in order along the arc; a loop when closed)
is taken at `RESOLUTION_RAD`: a point wherever the arc length crosses a multiple of it,
and its ends. Every point is checked free by coal (`CoalModel.free`) and each maximal run
of free points is a free piece (on a loop, a run may wrap round its end; a loop free all
along is one piece). A piece's length is the arc length along its points.

A returned configuration (member or path point) lies on the piece of its nearest
reference point (joint metric) when that point is within `MATCH_RAD` (the report's
coverage radius) and free; a piece of at least `MIN_PIECE_SHARE` of the fibre's length
is found when some returned configuration lies on it, and a returned component whose
configurations lie on two or more pieces of one exact curve is a merge across a
collision cut; one on pieces of two exact curves merges exact components (a kinematic
merge, as the kinematic report counts them). A missed piece is also looked for in the
answer with nothing checked: found there, the scene's answer lost it; not found, the
kinematic answer misses it too.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.joint_space import JointBox
from training.evaluate.metrics import COVERAGE_RADIUS_RAD

RESOLUTION_RAD = 0.025  # half the Panda reference's and the service's path step
MATCH_RAD = COVERAGE_RADIUS_RAD
MIN_PIECE_SHARE = 0.01  # of the fibre's length: smaller pieces are not asked to be found


def at_resolution(q_rad: FloatArray, step_rad: float = RESOLUTION_RAD) -> FloatArray:
    """The points of an ordered curve (k, n) where its arc length crosses a multiple of
    `step_rad`, and both ends."""
    if len(q_rad) < 3:
        return q_rad
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(q_rad, axis=0), axis=1))])
    bucket = np.floor(arc / step_rad)
    keep = np.concatenate([[True], bucket[1:] != bucket[:-1]])
    keep[-1] = True
    return q_rad[keep]


@dataclass(frozen=True)
class CutCurve:
    """One reference curve at resolution, its free points and its pieces."""

    q_rad: FloatArray  # (k, n) in order
    free: BoolArray  # (k,)
    piece: IntArray  # (k,) piece index within the curve, -1 where in collision
    piece_length_rad: FloatArray  # (p,)


def cut_curve(q_rad: FloatArray, closed: bool, free: BoolArray) -> CutCurve:
    """Maximal runs of free points of one curve (module docstring)."""
    step = np.linalg.norm(np.diff(q_rad, axis=0), axis=1)  # (k-1,) point i -> i+1
    if closed:
        step = np.append(step, np.linalg.norm(q_rad[0] - q_rad[-1]))
    piece = np.full(len(q_rad), -1)
    if free.all() and closed:
        return CutCurve(q_rad, free, np.zeros(len(q_rad), int), np.array([step.sum()]))
    order = np.arange(len(q_rad))
    if closed:  # start at a point in collision: no run wraps round the array's end
        order = np.roll(order, -int(np.flatnonzero(~free)[0]))
    edges = np.diff(np.concatenate([[0], free[order].astype(np.int8), [0]]))
    lengths = []
    for index, (start, stop) in enumerate(
        zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True)
    ):
        rows = order[start:stop]
        piece[rows] = index
        lengths.append(float(step[rows[:-1]].sum()))
    return CutCurve(q_rad, free, piece, np.array(lengths))


@dataclass(frozen=True)
class FreePieces:
    """Every free piece of a fibre: its reference points labelled by piece."""

    q_rad: FloatArray  # (P, n) every reference point at resolution
    label: IntArray  # (P,) piece over the whole fibre, -1 where in collision
    length_rad: FloatArray  # (L,) each piece's length
    curve: IntArray  # (L,) the exact curve each piece lies on
    fibre_length_rad: float  # every curve's length, free or not

    @classmethod
    def of(cls, curves: Sequence[CutCurve], fibre_length_rad: float) -> FreePieces:
        labels, offset = [], 0
        for curve in curves:
            labels.append(np.where(curve.piece >= 0, curve.piece + offset, -1))
            offset += len(curve.piece_length_rad)
        width = curves[0].q_rad.shape[1] if curves else 0
        return cls(
            q_rad=np.concatenate([c.q_rad for c in curves]) if curves else np.zeros((0, width)),
            label=np.concatenate(labels) if labels else np.zeros(0, int),
            length_rad=np.concatenate([c.piece_length_rad for c in curves] + [np.zeros(0)]),
            curve=np.concatenate(
                [np.full(len(c.piece_length_rad), i) for i, c in enumerate(curves)]
                + [np.zeros(0, int)]
            ),
            fibre_length_rad=fibre_length_rad,
        )

    @property
    def asked(self) -> BoolArray:  # (L,)
        """The pieces of at least MIN_PIECE_SHARE of the fibre's length."""
        return np.asarray(self.length_rad >= MIN_PIECE_SHARE * self.fibre_length_rad)

    def pieces_of(self, q_rad: FloatArray, periodic: BoolArray) -> IntArray:  # (K, n) -> (K,)
        """The piece each configuration lies on (module docstring), -1 for none."""
        if not len(q_rad) or not len(self.q_rad):
            return np.full(len(q_rad), -1)
        box = JointBox.covering(np.concatenate([q_rad, self.q_rad]), periodic, margin_rad=10.0)
        distance, nearest = box.tree(self.q_rad).query(box.points(q_rad))
        return np.where(distance <= MATCH_RAD, self.label[nearest], -1)


@dataclass(frozen=True)
class Recall:
    """The pieces found and the merges of one answer."""

    asked: int  # pieces of at least MIN_PIECE_SHARE of the fibre
    found: int  # of those, pieces some returned configuration lies on
    # Of the asked pieces, those with a point the service's check calls free (the others
    # are lost to the check's conservativeness: the service cannot return them), found.
    sphere_free: int
    sphere_free_found: int
    merges: int  # returned components on 2+ pieces of one exact curve: across a cut
    merges_of_curves: int  # returned components on pieces of 2+ exact curves
    missed_length_rad: list[float]  # the asked pieces not found
    missed_sphere_free_share: list[float]  # of each, the share of points the spheres free
    missed_kinematically: list[bool]  # of each, missed by the answer with nothing checked


def _merges(pieces: FreePieces, on: IntArray, labels: IntArray) -> tuple[int, int]:
    """Returned components on 2+ pieces of one curve, and on pieces of 2+ curves."""
    across_cut = across_curves = 0
    for component in np.unique(labels):
        held = np.unique(on[(labels == component) & (on >= 0)])
        curves = pieces.curve[held]
        across_curves += int(len(np.unique(curves)) > 1)
        across_cut += int(len(held) > len(np.unique(curves)))
    return across_cut, across_curves


def recall(
    pieces: FreePieces,
    sphere_free: BoolArray,  # (P,) the service's check on every reference point
    returned: FloatArray,  # (K, n)
    labels: IntArray,  # (K,) returned component of each
    periodic: BoolArray,
    kinematic: FloatArray | None = None,  # (J, n) returned with nothing checked
) -> Recall:
    """Found pieces and merges of the returned configurations (module docstring)."""
    count = len(pieces.length_rad)

    def hits(q_rad: FloatArray) -> tuple[IntArray, BoolArray]:
        on = pieces.pieces_of(q_rad, periodic)
        hit = np.zeros(count, dtype=bool)
        hit[on[on >= 0]] = True
        return on, hit

    on, hit = hits(returned)
    asked, inside = pieces.asked, pieces.label >= 0
    points = np.bincount(pieces.label[inside], minlength=count)
    freed = np.bincount(pieces.label[inside & sphere_free], minlength=count)
    missed = asked & ~hit
    kinematic_hit = hits(kinematic)[1] if kinematic is not None else np.zeros(count, bool)
    across_cut, across_curves = _merges(pieces, on, labels)
    return Recall(
        asked=int(asked.sum()),
        found=int((hit & asked).sum()),
        sphere_free=int((asked & (freed > 0)).sum()),
        sphere_free_found=int((asked & (freed > 0) & hit).sum()),
        merges=across_cut,
        merges_of_curves=across_curves,
        missed_length_rad=[float(x) for x in pieces.length_rad[missed]],
        missed_sphere_free_share=[float(x) for x in freed[missed] / np.maximum(points[missed], 1)],
        missed_kinematically=[bool(x) for x in ~kinematic_hit[missed]],
    )
