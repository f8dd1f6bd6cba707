"""Exact kinematics of the Franka Panda from Franka's published (modified, Craig) DH table:
forward kinematics, and the exact SMMs of a pose (1-D) and of a position (4-D), as the
evaluation's ground truth (numpy, float64).

Nothing here reads the URDF or shares code with pytorch-kinematics or the ONNX export;
the tests check this table against the bundled URDF with their own float64 chain.

The Panda has no closed-form arm angle like the iiwa's S-R-S: its elbow (a = 0.0825 m)
and wrist (a = 0.088 m) are offset. With joint 7 locked at a value q7, what is left is
a 6R arm whose first three axes meet at the shoulder (eaik classifies it as
6R-SPHERICAL_FIRST_TWO_INTERSECTING): `eaik` (Ostermeier et al., 2024) solves it in
closed form by subproblem decomposition, all branches, and flags least-squares (not
exact) rows. Sweeping q7
over its range gives exact points of the 1-D pose SMM; `pose_smm` chains them into
curves, joins the two branches that meet at each fold (where the curve turns back in
q7), fills fast swings, and cuts the curves by the joint limits.

eaik is an evaluation package (training/evaluate/packages.py): it is imported when a
solve runs (`locked_q7_robot`), not with this module, so that training and serving never
need it.

Angles come back in (-pi, pi]. Every joint's range but q6's lies inside (-pi, pi) so
the wrap is outside the limits; q6's range [-0.0175, 3.7525] straddles pi, so q6 is
kept in the chart [-0.0175, 2 pi - 0.0175), whose seam is the lower limit itself.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from training.evaluate.packages import requiring
from training.evaluate.references.iiwa14 import MIN_SHARE, PositionSmm
from training.evaluate.references.sweep import Sweep, swept, traced_paths

# Franka's modified DH table (frame i from i - 1: Rx(alpha) Tx(a) Rz(q) Tz(d)).
A_M = np.array([0.0, 0.0, 0.0, 0.0825, -0.0825, 0.0, 0.088])
D_M = np.array([0.333, 0.0, 0.316, 0.0, 0.384, 0.0, 0.0])
ALPHA_RAD = np.array([0.0, -np.pi / 2, np.pi / 2, np.pi / 2, -np.pi / 2, np.pi / 2, np.pi / 2])
FLANGE_M = 0.107  # link 8 beyond link 7 along z
HAND_YAW_RAD = -np.pi / 4  # the hand about the flange's z
TCP_M = 0.1034  # the TCP beyond the hand along z (the SRDF's end effector)
LOWER_RAD = np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
UPPER_RAD = np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])
TWO_PI = 2.0 * np.pi


def _mdh(q_rad: np.ndarray, a_m: float, d_m: float, alpha_rad: float) -> np.ndarray:
    """(B, 4, 4) modified DH link transforms Rx(alpha) Tx(a) Rz(q) Tz(d) for q (B,)."""
    ct, st = np.cos(q_rad), np.sin(q_rad)
    ca, sa = np.cos(alpha_rad), np.sin(alpha_rad)
    link = np.zeros((len(q_rad), 4, 4))
    link[:, 0] = np.stack([ct, -st, 0 * ct, a_m + 0 * ct], axis=1)
    link[:, 1] = np.stack([st * ca, ct * ca, -sa + 0 * ct, -d_m * sa + 0 * ct], axis=1)
    link[:, 2] = np.stack([st * sa, ct * sa, ca + 0 * ct, d_m * ca + 0 * ct], axis=1)
    link[:, 3, 3] = 1.0
    return link


def _tool() -> np.ndarray:
    """(4, 4) the TCP in the link-7 frame: flange, hand yaw, TCP offset."""
    c, s = np.cos(HAND_YAW_RAD), np.sin(HAND_YAW_RAD)
    tool = np.array([[c, -s, 0.0, 0.0], [s, c, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0, 0, 0, 1.0]])
    tool[2, 3] = FLANGE_M + TCP_M
    return tool


def joint_frames(q_rad: np.ndarray) -> np.ndarray:
    """(B, 8, 4, 4) the frames of joints 1-7 (each turns about its z) and of the TCP."""
    q_rad = np.atleast_2d(q_rad)
    pose = np.tile(np.eye(4), (len(q_rad), 1, 1))  # (B, 4, 4)
    frames = []
    for i in range(7):
        pose = pose @ _mdh(q_rad[:, i], A_M[i], D_M[i], ALPHA_RAD[i])
        frames.append(pose)
    frames.append(pose @ _tool())
    return np.stack(frames, axis=1)


def dh_pose(q_rad: np.ndarray) -> np.ndarray:
    """(B, 4, 4) TCP poses of configurations (B, 7)."""
    return joint_frames(q_rad)[:, -1]


def to_chart(q_rad: np.ndarray) -> np.ndarray:
    """(..., 7) the same configurations with q6 in [lower, lower + 2 pi) (see the module)."""
    q = np.array(q_rad, dtype=float)
    q[..., 5] = LOWER_RAD[5] + np.mod(q[..., 5] - LOWER_RAD[5], TWO_PI)
    return q


def within_limits(q_rad: np.ndarray) -> np.ndarray:
    return np.all((q_rad >= LOWER_RAD) & (q_rad <= UPPER_RAD), axis=-1)


_ZERO_POSE_FRAMES = joint_frames(np.zeros((1, 7)))[0]  # (8, 4, 4) what eaik is built from


def locked_q7_robot(q7_rad: float) -> Any:
    """eaik's 6R arm: the Panda with joint 7 locked at q7. eaik is imported here, not with
    the module, so that training and serving never need it; without it this raises
    MissingEvaluationPackage naming the command that installs it."""
    with requiring("eaik", "The Panda's exact reference (training/evaluate/references/panda.py)"):
        from eaik.IK_Homogeneous import HomogeneousRobot
    return HomogeneousRobot(_ZERO_POSE_FRAMES, fixed_axes=[(6, float(q7_rad))])


def solve_locked_q7(pose: np.ndarray, q7_rad: float) -> np.ndarray:
    """(k, 7) every exact configuration reaching `pose` (4, 4) with joint 7 at q7, no
    limits applied, q6 in the chart; eaik's least-squares rows are dropped."""
    solution = locked_q7_robot(q7_rad).IK(pose)
    q = np.asarray(solution.Q, dtype=float).reshape(-1, 7)[~np.asarray(solution.is_LS, bool)]
    return to_chart(q)


@dataclass(frozen=True)
class ReferenceComponent:
    """One feasible piece of a pose's SMM: points along it in order and its arc length."""

    q_rad: np.ndarray  # (k, 7) in order, <= max_step apart, ends within max_step of a limit
    arc_length_rad: float  # joint-space length (Euclidean; no Panda joint is periodic)
    closed: bool  # a loop inside the limits (the last point joins the first)


def pose_smm(
    position_m: np.ndarray,
    rotation: np.ndarray,
    q7_steps: int = 2000,
    max_step_rad: float = 0.05,
    min_width_rad: float = 1e-11,
) -> list[ReferenceComponent]:
    """The exact SMM of a pose within the joint limits, as its components.

    q7 is swept over its range at `q7_steps` values, each giving the fibre's exact points
    at that q7 (`solve_locked_q7`). Between neighbouring q7 values, points are linked
    one to one (mutual nearest on the wrapped joint distance) when the counts agree,
    every link is at most `max_step_rad` long and each is clearly the nearest (at most
    half the distance to any other candidate); otherwise the q7 interval is bisected,
    down to `min_width_rad`. An interval that narrow where the counts still differ holds
    a fold: the curve turns back in q7 and two points coalesce, so the two left over on
    the side with more points are one curve and are linked to each other (they are
    ~sqrt(width) apart). One where a link is still long is a fast swing next to a
    singular set (q2 ~ 0: joints 1 and 3 coaxial), filled with straight points. The
    linked points form paths and loops; each is cut where it leaves the limits.
    """
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rotation, position_m
    sweep = swept(
        lambda q7: solve_locked_q7(pose, q7), to_chart,
        np.linspace(LOWER_RAD[6], UPPER_RAD[6], q7_steps), max_step_rad, min_width_rad,
    )  # fmt: skip
    return _components(sweep)


def _components(sweep: Sweep) -> list[ReferenceComponent]:
    """Trace the linked points into paths and loops, then cut them by the limits."""
    return [c for path, closed in traced_paths(sweep) for c in _cut_by_limits(path, closed)]


def _cut_by_limits(path: np.ndarray, closed: bool) -> list[ReferenceComponent]:
    """The runs of `path` (k, 7) inside the limits, each a component."""
    feasible = within_limits(path)
    if closed and feasible.all():
        steps = np.linalg.norm(np.diff(np.concatenate([path, path[:1]]), axis=0), axis=1)
        return [ReferenceComponent(path, float(steps.sum()), closed=True)]
    if closed:  # start right after a point outside the limits
        path = np.roll(path, -int(np.flatnonzero(~feasible)[0]), axis=0)
        feasible = within_limits(path)
    edges = np.diff(np.concatenate([[0], feasible.astype(int), [0]]))
    components = []
    for first, end in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
        run = path[first:end]
        length = float(np.linalg.norm(np.diff(run, axis=0), axis=1).sum())
        components.append(ReferenceComponent(run, length, closed=False))
    return components


def fibonacci_sphere(count: int) -> np.ndarray:
    """(count, 3) unit vectors of equal-area cells (the Fibonacci lattice)."""
    index = np.arange(count) + 0.5
    z = 1.0 - 2.0 * index / count
    azimuth = np.pi * (1.0 + np.sqrt(5.0)) * index
    radius = np.sqrt(1.0 - z * z)
    return np.stack([radius * np.cos(azimuth), radius * np.sin(azimuth), z], axis=1)


def orientation_grid(sphere_steps: int, psi_steps: int) -> np.ndarray:
    """(S * K, 3, 3) rotations uniform under the Haar measure: the z axis on an equal-area
    sphere lattice (S) times K equal turns about it; cells ~ sqrt(4 pi / S) and 2 pi / K."""
    z_axis = fibonacci_sphere(sphere_steps)
    helper = np.where(np.abs(z_axis[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    y_axis = np.cross(z_axis, helper)
    y_axis /= np.linalg.norm(y_axis, axis=1, keepdims=True)
    frame = np.stack([np.cross(y_axis, z_axis), y_axis, z_axis], axis=2)  # (S, 3, 3)
    psi = np.linspace(-np.pi, np.pi, psi_steps, endpoint=False)
    turn = np.zeros((psi_steps, 3, 3))
    turn[:, 0, 0] = turn[:, 1, 1] = np.cos(psi)
    turn[:, 1, 0], turn[:, 0, 1] = np.sin(psi), -np.sin(psi)
    turn[:, 2, 2] = 1.0
    return (frame[:, None] @ turn[None]).reshape(-1, 3, 3)


def position_smm(
    position_m: np.ndarray,
    num_points: int = 20000,
    seed: int = 0,
    sphere_steps: int = 2000,
    psi_steps: int = 80,
    neighbours: int = 16,
) -> PositionSmm:
    """The exact SMM of a position within the joint limits: its components and points.

    The TCP lies on joint 7's axis (the tool is a pure offset along z7), so q7 does not
    move it: the fibre is the 3-D fibre of q1..q6 times the whole q7 range. With q7
    locked at 0, each TCP orientation R gives the fibre's points at R exactly (eaik, all
    branches); sweeping R over an SO(3) grid (`orientation_grid`, spacing h ~ 0.079 rad)
    covers the fibre, each in-limit solution a node weighted by its orientation cell
    (equal cells, so `share` is each component's fraction of the nodes).

    Components: nodes within `link_rad` = 4.5 h of each other in q1..q6 are linked (among
    each node's `neighbours` nearest). Why that radius: a node's neighbours on the same
    sheet are one grid step h away in orientation, hence gain * h away in q1..q6, where
    the gain |dq/dR| of the locked-q7 IK is ~1.5-3 away from its singular sets (measured:
    nearest-neighbour gaps have median 1.3 h and 99th percentile 2.2-3.6 h), so 4.5 h
    links a sheet's nodes to their grid neighbours with a margin; and two distinct
    components (separated by the limits, as every pair is) would need to come within
    4.5 h ~ 0.36 rad to be merged. Pieces closer than that count as one component, the
    same rule as the iiwa's contact radius. Where the gain is larger (next to a fold of
    the IK, or q2 ~ 0 where joints 1 and 3 are coaxial) a component can fall apart into
    slivers, which stay under MIN_SHARE and are not counted, or into pieces that are
    counted: the radius alone split one component in two on 11 of the 19 merges the first
    Panda position report charged to the service (`training.evaluate.merges`). So pieces
    are then joined on the fibre itself (`join_by_walks`): two pieces are one component
    when a straight walk between their closest nodes stays on the fibre.
    """
    rotation = orientation_grid(sphere_steps, psi_steps)
    spacing_rad = float(np.sqrt(4 * np.pi / sphere_steps))
    poses = np.tile(np.eye(4), (len(rotation), 1, 1))  # (S * K, 4, 4)
    poses[:, :3, :3], poses[:, :3, 3] = rotation, position_m
    solutions = locked_q7_robot(0.0).IK_batched(poses, 2)
    q = np.concatenate([np.reshape(s.Q, (-1, 7)) for s in solutions])  # (N, 7)
    exact = ~np.concatenate([np.asarray(s.is_LS, bool) for s in solutions])
    q = to_chart(q[exact])
    q6 = q[within_limits(q)][:, :6]  # (F, 6) the in-limit nodes, q7 = 0 dropped
    if not len(q6):
        return PositionSmm(np.zeros((0, 7)), np.zeros(0, int), np.zeros(0), spacing_rad)
    link_rad = 4.5 * spacing_rad
    distance, index = cKDTree(q6).query(
        q6, k=min(neighbours, len(q6)), distance_upper_bound=link_rad
    )
    near = np.isfinite(distance)
    first = np.broadcast_to(np.arange(len(q6))[:, None], index.shape)[near]
    graph = coo_matrix((np.ones(len(first)), (first, index[near])), shape=(len(q6), len(q6)))
    _, component = connected_components(graph, directed=False)
    component = join_by_walks(position_m, q6, component)
    share = np.bincount(component) / len(component)
    rng = np.random.default_rng(seed)
    drawn = rng.choice(len(q6), size=num_points)
    q7 = rng.uniform(LOWER_RAD[6], UPPER_RAD[6], num_points)
    return PositionSmm(
        np.concatenate([q6[drawn], q7[:, None]], axis=1), component[drawn], share, spacing_rad,
        q6.astype(np.float32), component,
    )  # fmt: skip


# The walk that joins two pieces of the 4-D reference (the projected local planner of
# constrained planning, OMPL's discreteGeodesic, here on the DH table alone): steps of
# WALK_STEP_RAD along the q1..q6 segment, each brought back to the position by
# Gauss-Newton to within WALK_TOLERANCE_M (the service's tolerance), inside the limits,
# no step longer than WALK_STRETCH x the step and no walk longer than WALK_STRETCH x the
# chord. Pieces whose closest nodes are more than JOIN_GAP_RAD apart are not tried.
WALK_STEP_RAD = 0.003
WALK_TOLERANCE_M = 1e-6
WALK_STRETCH = 2.0
WALK_NEWTON_ITERATIONS = 6
JOIN_GAP_RAD = 2.0


def tcp_position_and_jacobian(q6_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(B, 3) TCP positions and (B, 3, 6) their Jacobian in q1..q6, q7 = 0 (q7 does not
    move the TCP): column i is z_i x (p - o_i) for joint i's axis z_i through o_i."""
    frames = joint_frames(np.concatenate([q6_rad, np.zeros((len(q6_rad), 1))], axis=1))
    tcp = frames[:, 7, :3, 3]  # (B, 3)
    axis, origin = frames[:, :6, :3, 2], frames[:, :6, :3, 3]  # (B, 6, 3)
    return tcp, np.cross(axis, tcp[:, None] - origin).transpose(0, 2, 1)


def walks_join(
    position_m: np.ndarray,  # (3,)
    q_from_rad: np.ndarray,  # (E, 6) on the fibre, in the chart
    q_to_rad: np.ndarray,  # (E, 6)
) -> np.ndarray:  # (E,) bool
    """Whether a straight projected walk (the constants above) joins each pair, in lockstep."""
    num = len(q_from_rad)
    reached = np.zeros(num, dtype=bool)
    chord = np.linalg.norm(q_to_rad - q_from_rad, axis=1)  # (E,)
    q, travelled, walking = q_from_rad.copy(), np.zeros(num), np.ones(num, dtype=bool)
    for _ in range(int(np.ceil(WALK_STRETCH * chord.max(initial=0.0) / WALK_STEP_RAD)) + 2):
        remaining = q_to_rad - q  # (E, 6)
        distance = np.linalg.norm(remaining, axis=1)
        arrived = walking & (distance <= WALK_STEP_RAD)
        reached |= arrived
        walking &= ~arrived
        if not walking.any():
            break
        index = np.flatnonzero(walking)
        step = q[index] + WALK_STEP_RAD * remaining[index] / distance[index, None]  # (A, 6)
        error = np.full(len(index), np.inf)
        pending = np.arange(len(index))  # rows not yet within the tolerance
        for iteration in range(WALK_NEWTON_ITERATIONS + 1):
            tcp, jacobian = tcp_position_and_jacobian(step[pending])  # (P, 3), (P, 3, 6)
            residual = tcp - position_m
            error[pending] = np.linalg.norm(residual, axis=1)
            moving = error[pending] > WALK_TOLERANCE_M
            if iteration == WALK_NEWTON_ITERATIONS or not moving.any():
                break
            pending = pending[moving]
            newton = np.linalg.pinv(jacobian[moving])  # (P, 6, 3)
            step[pending] -= np.einsum("pij,pj->pi", newton, residual[moving])
        moved = np.linalg.norm(step - q[index], axis=1)
        inside = np.all((step >= LOWER_RAD[:6]) & (step <= UPPER_RAD[:6]), axis=1)
        ok = (
            (error <= WALK_TOLERANCE_M)
            & inside
            & (moved <= WALK_STRETCH * WALK_STEP_RAD)
            & (np.linalg.norm(q_to_rad[index] - step, axis=1) < distance[index])
            & (travelled[index] + moved <= WALK_STRETCH * chord[index])
        )
        walking[index[~ok]] = False
        q[index[ok]] = step[ok]
        travelled[index[ok]] += moved[ok]
    return reached


def join_by_walks(
    position_m: np.ndarray,  # (3,)
    q6_rad: np.ndarray,  # (F, 6) the fibre's nodes
    component: np.ndarray,  # (F,) their pieces by the link radius
) -> np.ndarray:  # (F,) pieces joined by walks, relabelled 0..C-1
    """Join every two counted pieces (MIN_SHARE of the nodes or more) whose closest nodes
    (at most JOIN_GAP_RAD apart) a straight projected walk (`walks_join`) joins. A failed
    walk proves nothing: pieces stay apart for want of such a walk. Slivers are not tried
    (hundreds of them next to a fold; they are not counted either way)."""
    pieces = int(component.max()) + 1 if len(component) else 0
    counted = np.flatnonzero(np.bincount(component, minlength=pieces) >= MIN_SHARE * len(component))
    if len(counted) < 2:
        return component
    trees = {c: cKDTree(q6_rad[component == c]) for c in counted.tolist()}
    members = {c: np.flatnonzero(component == c) for c in counted.tolist()}
    pairs, ends = [], []
    for a, b in itertools.combinations(counted.tolist(), 2):
        small, large = (a, b) if len(members[a]) <= len(members[b]) else (b, a)
        gap, nearest = trees[large].query(q6_rad[members[small]])
        best = int(np.argmin(gap))
        if gap[best] <= JOIN_GAP_RAD:
            pairs.append((a, b))
            ends.append((members[small][best], members[large][nearest[best]]))
    if not pairs:
        return component
    start, end = (np.array(column) for column in zip(*ends, strict=True))
    joined = walks_join(position_m, q6_rad[start], q6_rad[end])
    edges = np.array(pairs)[joined]
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(pieces, pieces))
    _, merged = connected_components(graph, directed=False)
    return merged[component]
