"""The exact SMM of an axis task as the union, over the free rotation psi about the tool
axis, of the exact fibres of full poses (evaluation ground truth; numpy, float64).

An axis target is a position p and a direction a* that the tool axis u (fixed in the
end-effector frame) must point along; the rotation about it is free. Its fibre is the
union over psi of the fibres of the poses (R0 Rot(u, psi), p), R0 any rotation with
R0 u = a*: for a 6-joint arm each pose has finitely many exact configurations (analytic
IK), so the union is 1-D; for a 7-joint arm each pose's fibre is 1-D (closed-form
charts), so the union is 2-D.

1-D (`ur5_axis_smm`): the exact points at psi round the circle are linked into curves
by `sweep.swept` (mutual nearest links, intervals bisected where a link is unclear,
folds joined), as the Panda's pose SMM is over q7; each curve's length is its size.
2-D (`axis_smm`): psi round the circle at `psi_steps` values; `exact_slice` gives each
pose's exact configurations grouped in connected pieces (ssik's in-limit arcs, glued),
and the pieces of neighbouring slices join where a point of one lies within `join_rad`
of a point of the other: the components are the connected groups of pieces, each sized
by its share of all slice points.

Two solvers, each independent of the service and of the export:
- `ur5_slice`: the UR5's analytic IK by eaik (Ostermeier et al., 2024: subproblem
  decomposition, all branches, least-squares rows flagged and dropped), built from the
  zero-pose joint frames of example-robot-data's URDF read by `urdf_chain`.
- `iiwa14_slice`: ssik's closed-form charts of the iiwa14 cut to the limits
  (`ssik_charts.chart_components`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from service.pipeline.joint_space import JointBox, wrap_to_pi
from training.evaluate.packages import requiring
from training.evaluate.references import iiwa14, ssik_charts
from training.evaluate.references.rotations import rodrigues
from training.evaluate.references.sweep import angle_gap, swept, traced_paths
from training.evaluate.references.urdf_chain import UrdfChain, read_chain

MODELS_DIR = Path(__file__).resolve().parents[3] / "models"
UR5_URDF = MODELS_DIR / "robots" / "ur5.urdf"
UR5_END_EFFECTOR = "tool0"
UR5_BASE = "base_link"
# The psi grid: 720 poses round the circle (0.5 degree apart).
PSI_STEPS = 720
# iiwa14: points every SPACING_RAD along each slice's arcs, and IIWA14_PSI_STEPS poses
# (3 degrees apart): about 4 s a target on this machine, for the report's 200.
SPACING_RAD = 0.04
IIWA14_PSI_STEPS = 120


@dataclass(frozen=True)
class Slice:
    """The exact configurations of one full pose, grouped by connected piece."""

    q_rad: np.ndarray  # (P, n)
    piece: np.ndarray  # (P,) 0..K-1


@dataclass(frozen=True)
class AxisSmm:
    """The axis target's exact SMM inside the limits, as labelled points."""

    q_rad: np.ndarray  # (P, n) every slice's points
    component: np.ndarray  # (P,) 0..C-1
    size: np.ndarray  # (C,) arc length in rad (1-D) or share of the points (2-D)

    @property
    def count(self) -> int:
        return len(self.size)


def poses_about(
    position_m: np.ndarray,  # (3,)
    axis: np.ndarray,  # (3,) a*, unit, base frame
    tool_axis: np.ndarray,  # (3,) u, unit, end-effector frame
    psi_rad: np.ndarray,  # (K,)
) -> np.ndarray:  # (K, 4, 4)
    """The full poses (R0 Rot(u, psi), p) whose tool axis points along a*."""
    u, target = np.asarray(tool_axis, float), np.asarray(axis, float)
    normal = np.cross(u, target)
    sine, cosine = np.linalg.norm(normal), float(u @ target)
    if sine < 1e-12:  # u along a* (R0 = I) or against it (a half turn about any normal)
        other = np.eye(3)[int(np.argmin(np.abs(u)))]
        normal = np.cross(u, other) if cosine < 0 else u
        sine = np.linalg.norm(normal)
    r0 = rodrigues(normal / sine, np.array([np.arctan2(sine, cosine)]))[0]
    poses = np.tile(np.eye(4), (len(psi_rad), 1, 1))
    poses[:, :3, :3] = r0 @ rodrigues(u, np.asarray(psi_rad, float))
    poses[:, :3, 3] = position_m
    return poses


def axis_smm(
    exact_slice: Callable[[np.ndarray], Slice],
    position_m: np.ndarray,
    axis: np.ndarray,
    tool_axis: np.ndarray,
    periodic: np.ndarray,  # (n,) joints compared on the circle
    join_rad: float,
    psi_steps: int = PSI_STEPS,
    apart: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> AxisSmm:
    """The 2-D components of the union over psi of `exact_slice`'s pieces (see the
    module), each sized by its share of the points. `apart` (P, n), (P, n) -> (P,) marks
    pairs of points that are never joined however near (on branches the fibre keeps
    apart)."""
    psi = np.linspace(-np.pi, np.pi, psi_steps, endpoint=False)
    slices = [exact_slice(pose) for pose in poses_about(position_m, axis, tool_axis, psi)]
    sizes = [len(s.q_rad) for s in slices]
    n = len(periodic)
    points = np.concatenate([s.q_rad for s in slices]) if sum(sizes) else np.zeros((0, n))
    if not len(points):
        return AxisSmm(points, np.zeros(0, np.int64), np.zeros(0))
    # Global piece numbers: slice k's piece j is offset[k] + j.
    piece_counts = [int(s.piece.max()) + 1 if len(s.piece) else 0 for s in slices]
    offset = np.concatenate([[0], np.cumsum(piece_counts)])
    point_piece = np.concatenate([s.piece + offset[k] for k, s in enumerate(slices)])
    box = JointBox.covering(points, np.asarray(periodic, bool), margin_rad=10.0)
    rows: list[np.ndarray] = []
    cols: list[np.ndarray] = []
    for k, current in enumerate(slices):
        following = slices[(k + 1) % len(slices)]
        if not len(current.q_rad) or not len(following.q_rad):
            continue
        distance, nearest = box.tree(following.q_rad).query(box.points(current.q_rad))
        near = distance <= join_rad
        if apart is not None:
            near &= ~apart(current.q_rad, following.q_rad[nearest])
        rows.append(current.piece[near] + offset[k])
        cols.append(following.piece[nearest[near]] + offset[(k + 1) % len(slices)])
    count = int(offset[-1])
    row = np.concatenate(rows or [np.zeros(0, int)])
    col = np.concatenate(cols or [np.zeros(0, int)])
    graph = coo_matrix((np.ones(len(row)), (row, col)), shape=(count, count))
    _, piece_component = connected_components(graph, directed=False)
    _, component = np.unique(piece_component[point_piece], return_inverse=True)
    size = np.bincount(component) / len(component)
    return AxisSmm(points, component.astype(np.int64), size.astype(np.float64))


# -- the UR5: eaik's analytic IK ---------------------------------------------------------


@cache
def ur5_chain() -> UrdfChain:
    return read_chain(UR5_URDF, UR5_END_EFFECTOR, UR5_BASE)


def _z_onto(axis: np.ndarray) -> np.ndarray:  # (3,) unit -> (3, 3) with R e_z = axis
    z = np.array([0.0, 0.0, 1.0])
    normal = np.cross(z, axis)
    sine, cosine = np.linalg.norm(normal), float(z @ axis)
    if sine < 1e-12:
        return np.eye(3) if cosine > 0 else np.diag([1.0, -1.0, -1.0])
    return rodrigues(normal / sine, np.array([np.arctan2(sine, cosine)]))[0]


@cache
def ur5_robot() -> Any:
    """eaik's UR5 from its joint frames at q = 0 (each turned so that z is the joint's
    axis) and the end effector's. eaik is imported here, not with the module."""
    with requiring("eaik", "The UR5's exact reference (training/evaluate/references/axis.py)"):
        from eaik.IK_Homogeneous import HomogeneousRobot
    chain = ur5_chain()
    frames, pose = chain.frames(np.zeros((1, len(chain.movable))))
    trafos = []
    for frame, joint in zip(frames[0], chain.movable, strict=True):
        turned = frame.copy()
        turned[:3, :3] = frame[:3, :3] @ _z_onto(joint.axis)
        trafos.append(turned)
    return HomogeneousRobot(np.stack([*trafos, pose[0]]))


def ur5_slice(pose: np.ndarray) -> Slice:
    """Every exact configuration of the UR5 at `pose` (4, 4), wrapped to (-pi, pi] (each
    UR5 joint turns a full circle), each its own piece."""
    solution = ur5_robot().IK(pose)
    q = np.asarray(solution.Q, dtype=float).reshape(-1, 6)[~np.asarray(solution.is_LS, bool)]
    return Slice(wrap_to_pi(q), np.arange(len(q)))


def ur5_axis_smm(position_m: np.ndarray, axis: np.ndarray, tool_axis: np.ndarray) -> AxisSmm:
    """The UR5 axis SMM (1-D, every joint periodic, so nothing is cut): eaik's exact
    points at PSI_STEPS values of psi round the circle, linked into loops by `sweep.swept`
    (links at most 0.05 rad, intervals bisected where unclear). Sizes are loop lengths."""

    def solve(psi: float) -> np.ndarray:
        return ur5_slice(poses_about(position_m, axis, tool_axis, np.array([psi]))[0]).q_rad

    sweep = swept(
        solve, wrap_to_pi, np.linspace(-np.pi, np.pi, PSI_STEPS + 1), max_step_rad=0.05,
        min_width_rad=1e-11, closed=True,
    )  # fmt: skip
    curves = traced_paths(sweep)
    if not curves:
        return AxisSmm(np.zeros((0, 6)), np.zeros(0, np.int64), np.zeros(0))
    lengths = [
        float(np.linalg.norm(angle_gap(path[:-1], path[1:]), axis=1).sum()) for path, _ in curves
    ]
    return AxisSmm(
        q_rad=np.concatenate([path for path, _ in curves]),
        component=np.concatenate([np.full(len(p), i) for i, (p, _) in enumerate(curves)]),
        size=np.array(lengths),
    )


# -- the iiwa14: ssik's closed-form charts --------------------------------------------------


def iiwa14_slice(pose: np.ndarray, lower_rad: np.ndarray, upper_rad: np.ndarray) -> Slice:
    """The iiwa14's in-limit arcs at `pose`, glued, with points SPACING_RAD apart."""
    charts = ssik_charts.chart_components("iiwa14", pose, lower_rad, upper_rad, SPACING_RAD)
    return Slice(charts.q_rad, charts.component)


def iiwa14_axis_smm(
    position_m: np.ndarray,
    axis: np.ndarray,
    tool_axis: np.ndarray,
    lower_rad: np.ndarray,
    upper_rad: np.ndarray,
    psi_steps: int = IIWA14_PSI_STEPS,
) -> AxisSmm:
    """The iiwa14 axis SMM (2-D): a join spans at most a slice's point spacing plus the
    grid step. Where the tool axis is joint 7's (the bundled model's), a point of one
    slice is its neighbour's with q7 moved by the step, so its nearest point in the
    neighbour is at most sqrt(step^2 + (spacing / 2)^2) away (0.056 rad), well inside;
    two pieces closer than the join (0.092 rad) at a limit are counted as one.

    With that tool axis the wrist centre W = p - 0.126 a* is fixed, so |q4| is fixed by
    |SW|: the elbow twins (q4 of either sign) meet only where the fibre reaches q4 = 0,
    the arm straight (|SW| = 0.82 m). Near that set the twins pass within the join of
    neighbouring poses, so points of opposite sign in q4 are never joined unless |SW|
    is within 1e-9 m of 0.82 m. (The shoulder twins meet where the elbow passes over the
    base axis, q2 = 0, which many targets reach: they are joined as any pieces are.)"""
    join_rad = SPACING_RAD + 2 * np.pi / psi_steps
    apart = None
    if np.allclose(tool_axis, [0.0, 0.0, 1.0]):
        wrist = position_m - iiwa14.WRIST_TO_EE_M * np.asarray(axis)
        shoulder_to_wrist = np.linalg.norm(wrist - iiwa14.SHOULDER_M)
        if iiwa14.UPPER_ARM_M + iiwa14.FOREARM_M - shoulder_to_wrist > 1e-9:

            def apart(q_a: np.ndarray, q_b: np.ndarray) -> np.ndarray:
                return np.asarray(np.sign(q_a[:, 3]) != np.sign(q_b[:, 3]))

    return axis_smm(
        lambda pose: iiwa14_slice(pose, lower_rad, upper_rad),
        position_m, axis, tool_axis, np.zeros(7, bool), join_rad, psi_steps, apart,
    )  # fmt: skip
