"""Exact kinematics of the iiwa14 from the paper's DH table: forward, closed-form S-R-S
inverse, and the exact SMM of a pose (evaluation ground truth; numpy, float64).

Nothing here shares code with the URDF, pytorch-kinematics or the ONNX export.

The iiwa's DH table is offset-free: joints 1-2 meet at the shoulder S = (0, 0, 0.36),
joint 4 sits at the elbow E with |SE| = 0.42 m, joints 5-7 meet at the wrist W with
|EW| = 0.40 m, and the end effector is 0.126 m beyond W along its own z axis. For a pose
(p, R): W = p - 0.126 R z. The elbow lies on a circle around the S-W axis, whose angle
is the arm angle psi. For every psi there are 8 configurations: the shoulder twin
(q1 + pi, -q2), the elbow twin (q3 + pi, -q4) and the wrist twin (q5 + pi, -q6, q7 + pi).
Sweeping psi around the circle for each of the 8 branches gives the whole unconstrained
fibre of the pose (8 closed loops); the joint limits cut it into the feasible components.
For a position alone the same IK, swept over the end-effector axis as well, gives the
4-D fibre (`position_smm`).

Derivation (standard DH, a = 0): the unit vector S->E is z_2 = (c1 s2, s1 s2, c2); in
frame 2, E->W is z_4 = (-c3 s4, -s3 s4, c4); and R_47 = R_04^T R has third column
(c5 s6, s5 s6, c6) and third row (-s6 c7, s6 s7, c6).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

# training/evaluate/iiwa14.py takes the rotation angle from here, with the DH FK.

D_M = np.array([0.360, 0.0, 0.420, 0.0, 0.400, 0.0, 0.081])  # seed Table 1; a = 0
ALPHA_RAD = np.radians([-90.0, 90.0, 90.0, -90.0, -90.0, 90.0, 0.0])
END_EFFECTOR_OFFSET_M = 0.045  # along the link-7 z axis (the flange)
TWO_PI = 2.0 * np.pi
LIMITS_RAD = np.radians([170.0, 120.0, 170.0, 120.0, 170.0, 120.0, 175.0])


def _dh_rotation(q_rad: np.ndarray, alpha_rad: float) -> np.ndarray:
    """(B, 3, 3) rotation of a standard DH link: Rz(q) Rx(alpha)."""
    ct, st = np.cos(q_rad), np.sin(q_rad)
    ca, sa = np.cos(alpha_rad), np.sin(alpha_rad)
    zero, one = np.zeros_like(ct), np.ones_like(ct)
    return np.stack(
        [
            np.stack([ct, -st * ca, st * sa], -1),
            np.stack([st, ct * ca, -ct * sa], -1),
            np.stack([zero, sa * one, ca * one], -1),
        ],
        -2,
    )


def dh_pose(q_rad: np.ndarray) -> np.ndarray:
    """(B, 4, 4) end-effector poses of configurations (B, 7) (or one (7,)): the product of
    the standard DH links A_i = Rz(q_i) Tz(d_i) Rx(alpha_i), then the flange along z."""
    q_rad = np.atleast_2d(q_rad)
    pose = np.tile(np.eye(4), (len(q_rad), 1, 1))  # (B, 4, 4)
    for i in range(7):
        link = np.tile(np.eye(4), (len(q_rad), 1, 1))
        link[:, :3, :3] = _dh_rotation(q_rad[:, i], ALPHA_RAD[i])
        link[:, 2, 3] = D_M[i]
        pose = pose @ link
    pose[:, :3, 3] += END_EFFECTOR_OFFSET_M * pose[:, :3, 2]
    return pose


SHOULDER_M = np.array([0.0, 0.0, D_M[0]])
UPPER_ARM_M = D_M[2]  # |SE|
FOREARM_M = D_M[4]  # |EW|
WRIST_TO_EE_M = D_M[6] + END_EFFECTOR_OFFSET_M
BRANCHES = [(s, e, w) for s in (1, -1) for e in (1, -1) for w in (1, -1)]


def wrist_centre(position_m: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    return position_m - WRIST_TO_EE_M * rotation[:, :, 2]  # (B, 3): along the EE z axis


def _perpendicular_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (3,) completing the unit `axis` to a right-handed frame."""
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(axis, u)


def elbow_positions(wrist_m: np.ndarray, psi_rad: np.ndarray) -> np.ndarray | None:
    """(K, 3) elbow on its circle for arm angles psi (K,); None when W is out of reach."""
    shoulder_to_wrist = wrist_m - SHOULDER_M
    distance = float(np.linalg.norm(shoulder_to_wrist))
    if not abs(UPPER_ARM_M - FOREARM_M) < distance < UPPER_ARM_M + FOREARM_M:
        return None
    axis = shoulder_to_wrist / distance
    along = (distance**2 + UPPER_ARM_M**2 - FOREARM_M**2) / (2 * distance)
    radius = np.sqrt(max(UPPER_ARM_M**2 - along**2, 0.0))
    u, v = _perpendicular_basis(axis)
    circle = np.cos(psi_rad)[:, None] * u + np.sin(psi_rad)[:, None] * v  # (K, 3)
    return SHOULDER_M + along * axis + radius * circle


def inverse_kinematics(
    position_m: np.ndarray, rotation: np.ndarray, psi_rad: np.ndarray, branch: tuple[int, int, int]
) -> np.ndarray | None:
    """(K, 7) configurations reaching the pose (p (3,), R (3, 3)) at arm angles psi (K,).

    `branch` = (shoulder, elbow, wrist) signs, each +1 or -1. Angles are in (-pi, pi];
    the joint limits are not applied. None when the pose is out of reach.
    """
    wrist_m = wrist_centre(position_m[None], rotation[None])[0]
    elbow_m = elbow_positions(wrist_m, psi_rad)
    if elbow_m is None:
        return None
    return _joint_angles(elbow_m, wrist_m, rotation, branch)


def _joint_angles(
    elbow_m: np.ndarray,  # (..., 3) the elbow E on its circle
    wrist_m: np.ndarray,  # (..., 3) the wrist centre W
    rotation: np.ndarray,  # (..., 3, 3) the end effector's rotation R
    branch: tuple[int, int, int],
) -> np.ndarray:
    """(..., 7) the S-R-S closed form (see the module): q1, q2 from S->E, q3, q4 from E->W
    in frame 2, q5..q7 from R_47 = R_04^T R; each pair's sign from `branch`."""
    shoulder, elbow, wrist = branch
    z2 = (elbow_m - SHOULDER_M) / UPPER_ARM_M  # (..., 3)
    q2 = shoulder * np.arccos(np.clip(z2[..., 2], -1.0, 1.0))
    q1 = np.arctan2(shoulder * z2[..., 1], shoulder * z2[..., 0])
    r_02 = _dh_rotation(q1, ALPHA_RAD[0]) @ _dh_rotation(q2, ALPHA_RAD[1])  # (..., 3, 3)
    z4 = np.einsum("...ji,...j->...i", r_02, (wrist_m - elbow_m) / FOREARM_M)  # in frame 2
    q4 = elbow * np.arccos(np.clip(z4[..., 2], -1.0, 1.0))
    q3 = np.arctan2(-elbow * z4[..., 1], -elbow * z4[..., 0])
    r_04 = r_02 @ _dh_rotation(q3, ALPHA_RAD[2]) @ _dh_rotation(q4, ALPHA_RAD[3])
    r_47 = np.swapaxes(r_04, -1, -2) @ rotation  # (..., 3, 3)
    q6 = wrist * np.arccos(np.clip(r_47[..., 2, 2], -1.0, 1.0))
    q5 = np.arctan2(wrist * r_47[..., 1, 2], wrist * r_47[..., 0, 2])
    q7 = np.arctan2(wrist * r_47[..., 2, 1], -wrist * r_47[..., 2, 0])
    return np.stack([q1, q2, q3, q4, q5, q6, q7], axis=-1)


@dataclass(frozen=True)
class ReferenceComponent:
    """One feasible piece of a pose's SMM: dense points along it and its arc length."""

    q_rad: np.ndarray  # (k, 7) ordered along the arc
    branch: tuple[int, int, int]
    arc_length_rad: float  # joint-space length (Euclidean; no iiwa joint is periodic)


def pose_smm(
    position_m: np.ndarray, rotation: np.ndarray, psi_steps: int = 7200, max_jump_rad: float = 0.2
) -> list[ReferenceComponent]:
    """The exact SMM of a pose within the joint limits, as its feasible components.

    Each branch's loop is sampled at `psi_steps` arm angles; consecutive feasible points
    belong to the same component when the arc between them stays inside the limits.
    Near a shoulder, elbow or wrist singularity the loop turns fast in joint space (two
    coaxial joints swing against each other while psi hardly moves), so consecutive
    samples can lie more than `max_jump_rad` apart on one continuous arc: such a step is
    resampled in psi until every step is short (`_arc_between`), and the arc is cut only
    where a resampled point leaves the limits. The loop closes: the last arc joins the
    first.
    """
    psi = np.linspace(-np.pi, np.pi, psi_steps, endpoint=False)
    components: list[ReferenceComponent] = []
    for branch in BRANCHES:
        q = inverse_kinematics(position_m, rotation, psi, branch)
        if q is None:
            return []
        feasible = np.all(np.abs(q) <= LIMITS_RAD, axis=1)  # (K,)
        following = np.roll(np.arange(len(psi)), -1)
        step = np.linalg.norm(q[following] - q, axis=1)  # (K,) to the next
        linked = feasible & feasible[following] & (step <= max_jump_rad)
        inserted: dict[int, np.ndarray] = {}  # resampled points after a sample, in order
        for jump in np.flatnonzero(feasible & feasible[following] & (step > max_jump_rad)).tolist():
            after = int(following[jump])
            psi_next = psi[after] + (TWO_PI if after == 0 else 0.0)
            arc = _arc_between(
                position_m, rotation, branch, psi[jump], psi_next, q[jump], q[after], max_jump_rad
            )
            if arc is not None:
                linked[jump] = True
                inserted[jump] = arc
                chain = np.concatenate([q[[jump]], arc, q[[after]]])
                step[jump] = float(np.linalg.norm(np.diff(chain, axis=0), axis=1).sum())
        if feasible.all() and linked.all():
            whole = _arc_points(q, inserted, list(range(len(psi))))
            whole = np.concatenate([whole, inserted.get(len(psi) - 1, q[:0])])
            components.append(ReferenceComponent(whole, branch, float(step.sum())))
            continue
        # Start right after a break, so no arc straddles the end of the array.
        start = int(np.flatnonzero(~linked)[0]) + 1
        order = np.roll(np.arange(len(psi)), -start)
        arc_members: list[int] = []
        for index in order.tolist():
            if feasible[index]:
                arc_members.append(index)
            if not linked[index] and arc_members:
                length = float(step[np.asarray(arc_members[:-1], dtype=int)].sum())
                components.append(
                    ReferenceComponent(_arc_points(q, inserted, arc_members), branch, length)
                )
                arc_members = []
    return components


def _arc_points(q: np.ndarray, inserted: dict[int, np.ndarray], members: list[int]) -> np.ndarray:
    """The samples q[members] (k, 7) of an arc in order, with the points resampled after
    each (`inserted`, by sample) between them."""
    rows = [q[[members[0]]]]
    for before, index in itertools.pairwise(members):
        rows += [inserted.get(before, q[:0]), q[[index]]]
    return np.concatenate(rows)


def _arc_between(
    position_m: np.ndarray,
    rotation: np.ndarray,
    branch: tuple[int, int, int],
    psi_a: float,
    psi_b: float,
    q_a: np.ndarray,  # (7,) the branch at psi_a
    q_b: np.ndarray,  # (7,) the branch at psi_b
    max_jump_rad: float,
    min_width_rad: float = 1e-12,
) -> np.ndarray | None:
    """The branch's points strictly between psi_a and psi_b (k, 7) in order, no two
    consecutive ones (ends included) more than `max_jump_rad` apart; None where the arc
    leaves the limits in between.

    Every interval whose ends are more than `max_jump_rad` apart is resampled at 15
    interior arm angles, down to `min_width_rad`. A step still long at that width is the
    branch crossing a singular set exactly: there the two coaxial joints are free to
    swing along a straight line, which stays inside the limits (a box) because both ends
    do; points along it fill the step. A resampled point outside the limits cuts the arc
    (it is also where the (-pi, pi] angles wrap, all outside the iiwa's limits).
    """
    found_psi: list[np.ndarray] = []
    found_q: list[np.ndarray] = []
    pending = [(psi_a, psi_b, q_a, q_b)]
    while pending:
        a, b, end_a, end_b = pending.pop()
        if b - a < min_width_rad:
            count = int(np.ceil(np.linalg.norm(end_b - end_a) / max_jump_rad))
            fraction = np.arange(1, count) / count  # (count - 1,) along the straight swing
            found_psi.append(a + (b - a) * fraction)
            found_q.append(end_a + fraction[:, None] * (end_b - end_a))
            continue
        psi = np.linspace(a, b, 17)
        inner = inverse_kinematics(position_m, rotation, psi[1:-1], branch)
        assert inner is not None  # the same wrist point as the ends, which are reachable
        if not np.all(np.abs(inner) <= LIMITS_RAD):
            return None
        found_psi.append(psi[1:-1])
        found_q.append(inner)
        q = np.concatenate([end_a[None], inner, end_b[None]])  # (17, 7)
        step = np.linalg.norm(np.diff(q, axis=0), axis=1)  # (16,)
        for k in np.flatnonzero(step > max_jump_rad).tolist():
            pending.append((psi[k], psi[k + 1], q[k], q[k + 1]))
    order = np.argsort(np.concatenate(found_psi), kind="stable")
    return np.concatenate(found_q)[order]


def rotations_with_z_axis(z_axis: np.ndarray) -> np.ndarray:
    """(D, 3, 3) rotations whose third column is the unit vector z_axis (D, 3), zero twist.

    R = Rz(azimuth) Ry(polar): continuous in the direction away from the poles.
    """
    polar = np.arccos(np.clip(z_axis[:, 2], -1.0, 1.0))
    azimuth = np.arctan2(z_axis[:, 1], z_axis[:, 0])
    ca, sa, cp, sp = np.cos(azimuth), np.sin(azimuth), np.cos(polar), np.sin(polar)
    return np.stack(
        [
            np.stack([ca * cp, -sa, ca * sp], -1),
            np.stack([sa * cp, ca, sa * sp], -1),
            np.stack([-sp, np.zeros_like(sp), cp], -1),
        ],
        -2,
    )


@dataclass(frozen=True)
class PositionSmm:
    """Exact points of the 4-D SMM of a position within the limits, by component.

    q7 does not move the end effector (it sits on joint 7's axis), so the fibre is the
    3-D fibre of q1..q6 times the whole q7 range. `share` is each component's fraction
    of the fibre, measured uniformly over (end-effector z axis on the sphere, arm angle,
    branch); components below `MIN_SHARE` are slivers at the grid's resolution and are
    not counted in `count`.
    """

    q_rad: np.ndarray  # (P, 7) exact points drawn uniformly over the fibre, q7 uniform
    component: np.ndarray  # (P,) component of each point
    share: np.ndarray  # (C,) fraction of the fibre in each component, all components
    spacing_rad: float  # grid step of the parametrisation (direction and psi)
    # Every in-limit node (q1..q6, float32) and its component: the densest labelling the
    # reference has, for the exact component of any configuration on the fibre. The
    # P drawn points alone are up to ~0.7 rad apart in q1..q6 where the IK's gain is
    # large (next to a singular set, where components come close): labelled by them, one
    # configuration of a component took a neighbour's label, a merge that was not.
    node_q6_rad: np.ndarray = field(default_factory=lambda: np.zeros((0, 6), np.float32))
    node_component: np.ndarray = field(default_factory=lambda: np.zeros(0, int))

    @property
    def count(self) -> int:
        return int(np.sum(self.share >= MIN_SHARE))


MIN_SHARE = 0.01


def position_smm(
    position_m: np.ndarray,
    num_points: int = 20000,
    seed: int = 0,
    grid_steps: int = 48,
    max_jump_rad: float = 1.0,
    contact_rad: float = 0.25,
) -> PositionSmm:
    """The exact SMM of a position within the joint limits: its components and points.

    Grid: the end-effector z axis over the sphere (`grid_steps` azimuths x
    `grid_steps` / 2 polar angles, cell centres), `grid_steps` arm angles psi, 8 branches;
    each node's q1..q6 is exact by the closed-form IK. Components of the feasible nodes:
    grid neighbours (along azimuth, polar angle or psi, same branch) are linked unless
    the IK jumps between them by more than `max_jump_rad` (at a shoulder, elbow or wrist
    singularity a branch's angles flip by pi, and the fibre continues in a twin
    branch); nodes closer than `contact_rad` are linked too, in the coordinates that
    `_contact_coordinates` gives near each singular set, which joins twin branches and
    the grid across the poles. Pieces closer than `contact_rad` count as one component.
    `num_points` nodes are drawn with the sphere's area weight and given q7 uniform in
    its range.
    """
    graph = position_graph(position_m, grid_steps, max_jump_rad, contact_rad)
    nodes = graph.grid.index[graph.grid.feasible]
    _, component = np.unique(graph.components()[nodes], return_inverse=True)  # 0..C-1
    return _drawn_fibre(graph.grid, graph.q6_rad[nodes], component, num_points, seed)


@dataclass(frozen=True)
class PositionGraph:
    """The reference's graph of a position's 4-D fibre (q1..q6; q7 is free): every grid
    node (feasible or not, row-major over the grid) then each singular set's exact
    points, and the links between them (`position_smm` says which)."""

    grid: _PositionGrid
    q6_rad: np.ndarray  # (N, 6) every node's q1..q6 (NaN at grid nodes out of reach)
    weight: np.ndarray  # (N,) a feasible grid node's sphere-area weight; 0 elsewhere
    link_from: np.ndarray  # (E,) node numbers
    link_to: np.ndarray  # (E,)

    def components(self, kept: np.ndarray | None = None) -> np.ndarray:  # (N,)
        """Connected components of the links between `kept` nodes (N,) (all: None)."""
        keep = np.ones(len(self.q6_rad), dtype=bool) if kept is None else kept
        both = keep[self.link_from] & keep[self.link_to]
        graph = coo_matrix(
            (np.ones(int(both.sum())), (self.link_from[both], self.link_to[both])),
            shape=(len(self.q6_rad), len(self.q6_rad)),
        )
        return np.asarray(connected_components(graph, directed=False)[1])


def position_graph(
    position_m: np.ndarray,
    grid_steps: int = 48,
    max_jump_rad: float = 1.0,
    contact_rad: float = 0.25,
) -> PositionGraph:
    """The nodes and links `position_smm` finds the components of (its docstring)."""
    grid = _position_grid(position_m, grid_steps)
    edges = _grid_links(grid, max_jump_rad)
    points6 = grid.q6[grid.feasible]  # (F, 6)
    contact, set_q6 = _contact_links(
        grid.index[grid.feasible], points6, grid.feasible.size, contact_rad, position_m
    )
    rows, cols = zip(*edges, *contact, strict=True)
    area = np.broadcast_to(np.sin(grid.polar_rad)[None, None, :, None], grid.feasible.shape)
    weight = np.concatenate([np.where(grid.feasible, area, 0.0).ravel(), np.zeros(len(set_q6))])
    return PositionGraph(
        grid=grid,
        q6_rad=np.concatenate([grid.q6.reshape(-1, 6), set_q6]),
        weight=weight,
        link_from=np.concatenate(rows).astype(np.int64),
        link_to=np.concatenate(cols).astype(np.int64),
    )


@dataclass(frozen=True)
class _PositionGrid:
    """The closed-form IK of a position on the grid (branch, azimuth, polar angle, psi)."""

    polar_rad: np.ndarray  # (P,) polar angles of the end-effector z axis (cell centres)
    q6: np.ndarray  # (8, A, P, K, 6) q1..q6 at every node, NaN where W is out of reach
    feasible: np.ndarray  # (8, A, P, K) within the limits of q1..q6 (False on NaN)
    index: np.ndarray  # (8, A, P, K) node numbers, row-major
    spacing_rad: float  # grid step of the direction and of psi


def _position_grid(position_m: np.ndarray, grid_steps: int) -> _PositionGrid:
    """Every branch's IK at every (end-effector z axis, arm angle) node of the grid."""
    n_azimuth, n_polar, n_psi = grid_steps, grid_steps // 2, grid_steps
    azimuth = np.linspace(-np.pi, np.pi, n_azimuth, endpoint=False)
    polar = (np.arange(n_polar) + 0.5) * np.pi / n_polar
    z_axis = np.stack(
        np.broadcast_arrays(
            np.sin(polar)[None] * np.cos(azimuth)[:, None],
            np.sin(polar)[None] * np.sin(azimuth)[:, None],
            np.cos(polar)[None] + 0 * azimuth[:, None],
        ),
        -1,
    ).reshape(-1, 3)  # (A * P, 3), azimuth-major
    rotation = rotations_with_z_axis(z_axis)
    psi = np.linspace(-np.pi, np.pi, n_psi, endpoint=False)
    # A fixed reference for psi = 0 per target keeps psi continuous across directions:
    # the S-W axis stays within 0.126 m of S-p, far from the helper when p is not at S.
    to_target = position_m - SHOULDER_M
    reference = _perpendicular_basis(to_target / np.linalg.norm(to_target))
    q = np.stack(
        [_inverse_kinematics_grid(position_m, rotation, psi, b, reference) for b in BRANCHES]
    )  # (8, A * P, K, 7), NaN where W is out of reach
    shape = (len(BRANCHES), n_azimuth, n_polar, n_psi)
    q6 = q[..., :6].reshape(*shape, 6)
    feasible = np.all(np.abs(q6) <= LIMITS_RAD[:6], axis=-1)  # (8, A, P, K); False on NaN
    index = np.arange(feasible.size).reshape(shape)
    return _PositionGrid(polar, q6, feasible, index, float(2 * np.pi / grid_steps))


def _grid_links(grid: _PositionGrid, max_jump_rad: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """(from, to) node pairs of feasible grid neighbours along azimuth, polar angle and psi
    (same branch) that the IK does not jump between by more than `max_jump_rad`."""
    edges = []
    for axis, periodic in ((1, True), (2, False), (3, True)):
        after = np.roll(grid.index, -1, axis=axis)
        jump = np.linalg.norm(grid.q6 - np.roll(grid.q6, -1, axis=axis), axis=-1)
        linked = grid.feasible & np.roll(grid.feasible, -1, axis=axis) & (jump <= max_jump_rad)
        if not periodic:  # the last polar row has no successor
            np.moveaxis(linked, axis, 0)[-1] = False
        edges.append((grid.index[linked], after[linked]))
    return edges


def _contact_links(
    nodes: np.ndarray,  # (F,) node numbers of the feasible nodes
    points6: np.ndarray,  # (F, 6) their q1..q6
    num_nodes: int,
    contact_rad: float,
    position_m: np.ndarray,
) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray]:
    """(from, to) node pairs closer than `contact_rad` in each of `_contact_coordinates`,
    and the q1..q6 (S, 6) of the singular sets' exact points, added as extra nodes
    numbered from `num_nodes` on."""
    edges = []
    extra = [np.zeros((0, 6))]
    for coordinates, near, on_set, exact in _contact_coordinates(points6, contact_rad, position_m):
        # Nodes within contact_rad of each other, near the set, are one component only
        # where the fibre really reaches the set: each is linked to the exact points of
        # the set within contact_rad (set points are extra graph nodes, joined along
        # the set), never to each other across a gap the fibre does not cross.
        if on_set is None:
            pairs = cKDTree(coordinates).query_pairs(contact_rad, output_type="ndarray")
            edges.append((nodes[near][pairs[:, 0]], nodes[near][pairs[:, 1]]))
            continue
        set_index = num_nodes + np.arange(len(on_set))
        num_nodes += len(on_set)
        extra.append(exact)
        tree = cKDTree(on_set)
        for node, hits in zip(nodes[near], tree.query_ball_point(coordinates, contact_rad),
                              strict=True):  # fmt: skip
            edges.append((np.full(len(hits), node), set_index[np.asarray(hits, dtype=np.int64)]))
        pairs = tree.query_pairs(contact_rad, output_type="ndarray")  # along the set
        edges.append((set_index[pairs[:, 0]], set_index[pairs[:, 1]]))
    return edges, np.concatenate(extra)


def _drawn_fibre(
    grid: _PositionGrid,
    points6: np.ndarray,  # (F, 6) q1..q6 of the feasible nodes
    component: np.ndarray,  # (F,) their components, 0..C-1
    num_points: int,
    seed: int,
) -> PositionSmm:
    """`num_points` feasible nodes drawn with the sphere's area weight, q7 uniform in its
    range, and each component's share of the fibre."""
    if len(points6) == 0:
        return PositionSmm(np.zeros((0, 7)), np.zeros(0, int), np.zeros(0), grid.spacing_rad)
    area = np.broadcast_to(np.sin(grid.polar_rad)[None, None, :, None], grid.feasible.shape)
    area = area[grid.feasible]  # (F,)
    share = np.bincount(component, weights=area) / area.sum()  # of the feasible fibre
    rng = np.random.default_rng(seed)
    drawn = rng.choice(len(points6), size=num_points, p=area / area.sum())
    q7 = rng.uniform(-LIMITS_RAD[6], LIMITS_RAD[6], num_points)
    return PositionSmm(
        np.concatenate([points6[drawn], q7[:, None]], axis=1),
        component[drawn],
        share,
        grid.spacing_rad,
        points6.astype(np.float32),
        component,
    )


def _contact_coordinates(
    q6_rad: np.ndarray, contact_rad: float, position_m: np.ndarray
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]]:
    """Coordinates (and the rows they cover) in which nearby nodes are one component, with
    the exact points of the singular set in the same coordinates (None: no set) and as
    they are, q1..q6.

    First q1..q6 themselves. Then each singular set: at q2 = 0 only q1 + q3 moves the
    arm, at q4 = 0 only q3 + q5, and at q6 = 0 joint 5 no longer moves the end-effector
    position; there the fibre holds a whole segment of the free combination, which joins
    the twin branches. Nodes near a singular set are compared without that free
    direction, and only with exact points of the set (`singular_set_points`): a fibre
    that comes near a set without reaching it (the shoulder's q2 = 0 puts the elbow
    0.42 m above the shoulder, out of reach of some targets) does not join its twins.
    """
    q = q6_rad
    sets: list[tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]] = [
        (q, np.ones(len(q), dtype=bool), None, np.zeros((0, 6)))
    ]
    set_points = singular_set_points(position_m)
    for joint, exact in set_points.items():
        near = np.abs(q[:, joint]) < contact_rad
        sets.append((_reduced(q[near], joint), near, _reduced(exact, joint), exact))
    return sets


def _reduced(q: np.ndarray, joint: int) -> np.ndarray:
    """q1..q6 (P, 6) without the free direction of the singular set q_joint = 0."""
    if joint == 1:  # shoulder: q1 + q3
        return np.stack([q[:, 0] + q[:, 2], q[:, 1], q[:, 3], q[:, 4], q[:, 5]], 1)
    if joint == 3:  # elbow: q3 + q5
        return np.stack([q[:, 0], q[:, 1], q[:, 2] + q[:, 4], q[:, 3], q[:, 5]], 1)
    return q[:, [0, 1, 2, 3, 5]]  # wrist: q5 is free


def _sphere_circle(
    centre_a: np.ndarray, radius_a: float, centre_b: np.ndarray, radius_b: float, steps: int
) -> np.ndarray:
    """(steps, 3) points of the circle where two spheres meet; (0, 3) when they do not."""
    axis = centre_b - centre_a
    distance = float(np.linalg.norm(axis))
    if not abs(radius_a - radius_b) <= distance <= radius_a + radius_b or distance == 0.0:
        return np.zeros((0, 3))
    axis /= distance
    along = (distance**2 + radius_a**2 - radius_b**2) / (2 * distance)
    radius = np.sqrt(max(radius_a**2 - along**2, 0.0))
    u, v = _perpendicular_basis(axis)
    phi = np.linspace(-np.pi, np.pi, steps, endpoint=False)
    return centre_a + along * axis + radius * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v)


def singular_set_points(position_m: np.ndarray, steps: int = 720) -> dict[int, np.ndarray]:
    """Exact q1..q6 (P, 6) on each singular set the position's fibre reaches, keyed by the
    joint that is 0 there (1: shoulder q2, 3: elbow q4, 5: wrist q6); feasible in every
    joint but the set's free pair (any value of the free combination fits the limits).

    Shoulder (q2 = 0): the elbow is E = S + 0.42 z, so W lies on the circle where the
    sphere of radius 0.40 about E meets the sphere of radius 0.126 about p. Elbow
    (q4 = 0): |SW| = 0.82 (taken 1e-7 m short, where the IK is defined). Wrist (q6 = 0):
    the end effector continues the forearm, so E lies where the sphere of radius 0.42
    about S meets the sphere of radius 0.526 about p. Every branch's IK at those points.
    """
    up = np.array([0.0, 0.0, 1.0])
    elbow_up = SHOULDER_M + UPPER_ARM_M * up
    cases: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # joint -> (wrist W, elbow E)
    wrist = _sphere_circle(elbow_up, FOREARM_M, position_m, WRIST_TO_EE_M, steps)
    cases[1] = (wrist, np.broadcast_to(elbow_up, wrist.shape))
    straight = UPPER_ARM_M + FOREARM_M - 1e-7
    wrist = _sphere_circle(SHOULDER_M, straight, position_m, WRIST_TO_EE_M, steps)
    cases[3] = (wrist, SHOULDER_M + UPPER_ARM_M * (wrist - SHOULDER_M) / straight)
    elbow = _sphere_circle(SHOULDER_M, UPPER_ARM_M, position_m, FOREARM_M + WRIST_TO_EE_M, steps)
    forearm = (position_m - elbow) / (FOREARM_M + WRIST_TO_EE_M)
    cases[5] = (elbow + FOREARM_M * forearm, elbow)
    free = {1: [0, 2], 3: [2, 4], 5: [4]}
    to_target = position_m - SHOULDER_M  # psi's reference, as in position_smm
    reference = _perpendicular_basis(to_target / np.linalg.norm(to_target))
    points: dict[int, np.ndarray] = {}
    for joint, (wrist_m, elbow_m) in cases.items():
        if not len(wrist_m):
            continue
        z_axis = (position_m - wrist_m) / WRIST_TO_EE_M  # (D, 3)
        rotation = rotations_with_z_axis(z_axis / np.linalg.norm(z_axis, axis=1, keepdims=True))
        axis = (wrist_m - SHOULDER_M) / np.linalg.norm(wrist_m - SHOULDER_M, axis=1, keepdims=True)
        u, v = _circle_basis(axis, reference)
        to_elbow = elbow_m - SHOULDER_M  # its part across the S-W axis gives psi
        psi = np.arctan2(np.sum(to_elbow * v, axis=1), np.sum(to_elbow * u, axis=1))  # (D,)
        q = np.concatenate(
            [_inverse_kinematics_grid(position_m, rotation, psi[:, None], b, reference)[:, 0, :6]
             for b in BRANCHES]
        )  # fmt: skip
        q = q[np.all(np.isfinite(q), axis=1)]
        if joint in (1, 3):
            # On the set q_i and q_k alone are arbitrary (the IK picks one split) and only
            # their sum is fixed, up to a turn: every sum the limits allow is a line of the
            # fibre, so each gets its points (q_i shifted by a turn).
            i, k = free[joint]
            q = np.concatenate([q + shift * TWO_PI * np.eye(6)[i] for shift in (-1, 0, 1)])
            q = q[np.abs(q[:, i] + q[:, k]) <= LIMITS_RAD[i] + LIMITS_RAD[k]]
        if not len(q):
            continue
        checked = np.ones(6, dtype=bool)
        checked[free[joint]] = False
        feasible = np.all(np.abs(q[:, checked]) <= LIMITS_RAD[:6][checked], axis=1)
        if feasible.any():
            points[joint] = q[feasible]
    return points


def _circle_basis(
    axis: np.ndarray, reference: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """(D, 3) x 2: the fixed `reference` projected onto the plane across each unit S-W axis
    (D, 3), and its quarter turn: psi = 0 and psi = pi / 2 on each elbow circle."""
    u = reference[0] - np.sum(reference[0] * axis, axis=1, keepdims=True) * axis
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(axis, u)


def _inverse_kinematics_grid(
    position_m: np.ndarray,
    rotation: np.ndarray,
    psi_rad: np.ndarray,
    branch: tuple[int, int, int],
    reference: tuple[np.ndarray, np.ndarray],
) -> np.ndarray:
    """(D, K, 7) IK for many end-effector rotations (D, 3, 3) at once; NaN where out of reach.

    psi (K,) for every rotation, or (D, K) per rotation, is measured from the fixed
    `reference` basis projected onto each circle's plane, so neighbouring rotations get
    neighbouring elbows.
    """
    wrist_m = wrist_centre(position_m, rotation)  # (D, 3)
    shoulder_to_wrist = wrist_m - SHOULDER_M
    distance = np.linalg.norm(shoulder_to_wrist, axis=1, keepdims=True)  # (D, 1)
    reachable = (abs(UPPER_ARM_M - FOREARM_M) < distance) & (distance < UPPER_ARM_M + FOREARM_M)
    distance = np.where(reachable, distance, 1.0)
    axis = shoulder_to_wrist / distance  # (D, 3)
    along = (distance**2 + UPPER_ARM_M**2 - FOREARM_M**2) / (2 * distance)  # (D, 1)
    radius = np.sqrt(np.clip(UPPER_ARM_M**2 - along**2, 0.0, None))
    u, v = _circle_basis(axis, reference)
    psi = np.atleast_2d(psi_rad)  # (1, K) or (D, K)
    circle = np.cos(psi)[..., None] * u[:, None] + np.sin(psi)[..., None] * v[:, None]
    elbow_m = SHOULDER_M + (along * axis)[:, None] + radius[:, :, None] * circle  # (D, K, 3)
    q = _joint_angles(elbow_m, wrist_m[:, None], rotation[:, None], branch)  # (D, K, 7)
    return np.where(reachable[:, :, None], q, np.nan)
