"""tracing: seeds are spread on the joint torus, a whole turn apart counting as no apart,
an angle a rounding below 0 (which np.mod maps onto 2 pi itself) is a valid seed, and the
seeds are the in-order greedy choice; the Hermite guesses between traced points follow a
curve to fourth order; every path point of a traced iiwa pose fibre comes back with the
error measured at that very point, exact, inside the limits and finely spaced, and open
paths end on a limit; the compiled closest approach of two strands is the numpy steps'
answer on a KD-tree to the bit."""

from collections.abc import Sequence

import numpy as np
import pytest
from scipy.spatial import cKDTree

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline import native
from service.pipeline.arrays import FloatArray, IntArray
from service.pipeline.connect.trace import TraceSettings, closest_strands_rad, trace_fibre
from service.pipeline.connect.trace.cut import hermite
from service.pipeline.connect.trace.seeds import spread_seeds
from service.pipeline.connect.trace.strands import STRAND_ARC_FACTOR
from service.pipeline.joint_space import JointLimits, joint_difference, joint_distance
from tests.service.pipeline.fibre_support import fibre_space, pose_fibre
from training.evaluate.references.iiwa14 import pose_smm

SETTINGS = TraceSettings(
    step_rad=0.15, max_steps=200, seed_spacing_rad=1.0, path_spacing_rad=0.05
)  # the bundled models' defaults


@pytest.fixture(scope="module")
def iiwa14_pose() -> ServedModel:
    return load_model(REPO_MODELS_DIR / "iiwa14-pose", threads=1)


def test_seeds_are_spread_on_the_torus_and_survive_angles_rounding_to_2_pi() -> None:
    q = np.array(
        [
            [-1e-17, 0.0, 0.0],  # np.mod(-1e-17, 2 pi) == 2 pi in float64
            [2 * np.pi - 1e-3, 0.0, 0.0],  # 1e-3 rad from the first, round the circle
            [1.0, 0.0, 0.0],
            [1.05, 0.0, 0.0],
            [-2.0, 0.5, 0.0],
        ]
    )
    seeds = spread_seeds(q, spacing_rad=0.2)
    np.testing.assert_array_equal(seeds, q[[0, 2, 4]])


@pytest.mark.parametrize("spacing", [0.3, 1.0, 2.5])
def test_seeds_are_the_greedy_choice_in_order(spacing: float) -> None:
    """The compiled choice picks exactly the points the one-by-one greedy choice over the
    torus distance picks."""
    rng = np.random.default_rng(6)
    q = rng.uniform(-4.0, 4.0, (300, 4))
    q[150:] = q[:150] + rng.normal(scale=0.2, size=(150, 4))  # pairs near each other
    chosen: list[int] = []
    for i in range(len(q)):
        if all(joint_distance(q[i], q[j], np.ones(4, bool)) > spacing for j in chosen):
            chosen.append(i)
    np.testing.assert_array_equal(spread_seeds(q, spacing), q[chosen])


def test_hermite_follows_a_circle_to_fourth_order() -> None:
    """Between two points of a unit circle with their tangents, the Hermite point is off
    the circle by O(L^4) (the chord's midpoint by L^2 / 8), and its direction is the
    circle's tangent there to O(L^3)."""
    for arc in (0.15, 0.075):
        theta = np.array([0.3, 0.3 + arc])
        p = np.stack([np.cos(theta), np.sin(theta)], axis=1)  # (2, 2)
        t = np.stack([-np.sin(theta), np.cos(theta)], axis=1)
        s = np.array([0.25, 0.5, 0.75])
        point, direction = hermite(
            np.repeat(p[:1], 3, 0), np.repeat(t[:1], 3, 0), np.repeat(p[1:], 3, 0),
            np.repeat(t[1:], 3, 0), s,
        )  # fmt: skip
        assert np.abs(np.linalg.norm(point, axis=1) - 1.0).max() < 0.01 * arc**4
        angle = np.arctan2(point[:, 1], point[:, 0])
        along = np.stack([-np.sin(angle), np.cos(angle)], axis=1)
        assert np.abs(direction - along).max() < 0.05 * arc**3


def test_every_path_point_is_exact_where_it_is_returned(iiwa14_pose: ServedModel) -> None:
    """A traced pose fibre (samples: exact S-R-S points): each returned error is the one
    the kinematics measures at the returned point, within 1e-9; the points are inside
    the limits and at most 0.05 rad apart; an open path ends on a joint limit."""
    manifest = iiwa14_pose.manifest
    limits = JointLimits.of(manifest.joints)
    lower, upper, periodic = limits.lower_rad, limits.upper_rad, limits.periodic
    q_target = np.random.default_rng(8).uniform(0.8 * lower, 0.8 * upper)
    fibre = pose_fibre(iiwa14_pose, q_target)
    fk = iiwa14_pose.kinematics(q_target[None])
    exact = pose_smm(fk.position_m[0], fk.rotation[0])
    samples = np.concatenate([component.q_rad[::150] for component in exact])
    trace = trace_fibre(fibre_space(fibre, limits, ()), samples, SETTINGS)
    assert trace.complete and len(trace.pieces) == len(exact)
    for piece in trace.pieces:
        q = piece.path_rad
        # The same point read in its joints' window: the angles round by ~1e-16 rad.
        np.testing.assert_allclose(fibre.residual(q)[0], piece.error, rtol=0, atol=1e-13)
        assert np.linalg.norm(piece.error, axis=1).max() <= 1e-9
        assert np.all(periodic | ((q >= lower) & (q <= upper)))
        gaps = joint_distance(q[1:], q[:-1], periodic)
        if piece.closed:
            gaps = np.append(gaps, joint_distance(q[-1], q[0], periodic))
        else:
            for end in (q[0], q[-1]):
                assert np.minimum(end - lower, upper - end)[~periodic].min() <= 1e-12
        assert gaps.max() <= SETTINGS.path_spacing_rad


Curves = list[tuple[np.ndarray, bool]]


def torus(periodic: np.ndarray) -> JointLimits:
    """Joint limits with these joints periodic (closest_strands_rad reads only which are:
    the others get limits of +-pi, which it does not read)."""
    return JointLimits(np.full(len(periodic), -np.pi), np.full(len(periodic), np.pi), periodic)


def _curves(*curves: tuple[np.ndarray, bool]) -> tuple[Curves, JointLimits]:
    """The curves with every joint periodic (the tracer's torus)."""
    return list(curves), torus(np.ones(curves[0][0].shape[1], dtype=bool))


def brute_force_closest_strands(curves: Curves, periodic: np.ndarray, within_rad: float) -> float:
    """closest_strands_rad's definition, every pair of points measured (O(P^2))."""
    best = np.inf
    for c, (q_c, closed_c) in enumerate(curves):
        arc = np.concatenate([[0.0], np.cumsum(joint_distance(q_c[1:], q_c[:-1], periodic))])
        total = arc[-1] + (float(joint_distance(q_c[0], q_c[-1], periodic)) if closed_c else 0)
        for d, (q_d, _) in enumerate(curves):
            gap = joint_distance(q_c[:, None, :], q_d[None, :, :], periodic)  # (P_c, P_d)
            if c == d:
                along = np.abs(arc[:, None] - arc[None, :])
                if closed_c:
                    along = np.minimum(along, total - along)
                gap = np.where(along > STRAND_ARC_FACTOR * within_rad, gap, np.inf)
            gap = gap[gap <= within_rad]
            best = min(best, float(gap.min(initial=np.inf)))
    return best


@pytest.mark.parametrize("seed", range(40))
def test_closest_strands_equal_every_pair_measured(seed: int) -> None:
    """The grouped KD-tree misses no pair: random walks, closed or not, on a torus with
    some limited joints, at step lengths from well under to over the distance asked."""
    rng = np.random.default_rng(seed)
    periodic = rng.random(3) < 0.5
    curves = []
    for _ in range(int(rng.integers(1, 4))):
        step = rng.choice([0.01, 0.04, 0.1, 0.3])
        q = np.cumsum(rng.normal(0, step, (int(rng.integers(1, 60)), 3)), axis=0)
        curves.append((q + rng.normal(0, 0.3, 3), bool(rng.random() < 0.3)))
    for within in (0.05, 0.165, 0.4):
        assert closest_strands_rad(curves, torus(periodic), within) == pytest.approx(
            brute_force_closest_strands(curves, periodic, within), abs=1e-12
        )


def test_closest_strands_are_two_curves_or_a_hairpin_never_neighbours() -> None:
    s = np.linspace(0.0, 2.0, 81)[:, None]  # 0.025 rad steps
    line = np.concatenate([s, np.zeros_like(s)], axis=1)  # (81, 2)
    within = 0.165  # the fronts' meeting distance at h = 0.15
    # One straight curve: only neighbours along it are near each other.
    assert closest_strands_rad(*_curves((line, False)), within) == np.inf
    # A parallel twin 0.04 rad away (and one 0.3 rad away, beyond the meeting distance).
    twin = line + np.array([0.0, 0.04])
    assert closest_strands_rad(*_curves((line, False), (twin, False)), within) == pytest.approx(
        0.04
    )
    far = line + np.array([0.0, 0.3])
    assert closest_strands_rad(*_curves((line, False), (far, False)), within) == np.inf
    # A hairpin: out along the line and back 0.1 rad beside it, one curve.
    hairpin = np.concatenate([line, (line + np.array([0.0, 0.1]))[::-1]])
    assert closest_strands_rad(*_curves((hairpin, False)), within) == pytest.approx(0.1)
    # A closed circle of radius 1: its first and last points are neighbours across the
    # closing step, not strands.
    theta = np.linspace(0.0, 2 * np.pi, 252, endpoint=False)[:, None]
    circle = np.concatenate([np.cos(theta), np.sin(theta)], axis=1)
    assert closest_strands_rad(*_curves((circle, True)), within) == np.inf
    # A limited joint does not wrap: a twin a whole turn away on it is far.
    limited = [(line, False), (twin + np.array([0.0, 2 * np.pi]), False)]
    assert closest_strands_rad(limited, torus(np.array([True, False])), within) == np.inf
    # On the torus: a twin read a whole turn away is as near as one beside it.
    turned = twin + np.array([2 * np.pi, -2 * np.pi])
    assert closest_strands_rad(*_curves((line, False), (turned, False)), within) == pytest.approx(
        0.04
    )


STRAND_GROUP = 3  # consecutive path points per point of the tree


def numpy_closest_strands_rad(
    curves: Sequence[tuple[FloatArray, bool]],  # (P_c, n) ordered points, closed or not
    limits: JointLimits,
    within_rad: float,
) -> float:
    """strands.py's closest approach of two strands as numpy steps on a KD-tree of every
    STRAND_GROUP-th path point (native.closest_strands): points of
    two different curves, or of one curve but more than STRAND_ARC_FACTOR x `within_rad`
    apart along it (the shorter way round a closed one); inf when none is within
    `within_rad`.

    Fronts meet within 1.1 h, so two strands closer than that are told apart only by the
    twins test of `meet`, and a fibre that runs as twins closer than the test resolves
    is traced as the wrong curves: the structure there is ambiguous. Candidate pairs come
    from a KD-tree on the limited joints as they are and the periodic ones embedded on
    circles (cos q, sin q), whose chord is never longer than their angle, so no pair
    within the distance is missed.

    The tree holds one point in STRAND_GROUP along each curve, its group's middle one:
    two points within `within_rad` have group points within `within_rad` + 2 delta (delta
    the longest arc from a point to its group's), so those group pairs, less the ones
    too near along one curve for any of their points to be two strands, give every
    candidate, and each is then measured point by point. Most pairs within the distance
    are neighbours on one strand; the coarser tree skips them (3 ms to 1 ms for the 1700
    path points of an iiwa pose target).
    """
    curves = [(q, closed) for q, closed in curves if len(q)]
    if not curves:
        return np.inf
    periodic = limits.periodic
    points = np.concatenate([q for q, _ in curves])  # (P, n)
    # Every step at once (across two curves' boundary too, left out below), each curve's
    # arc the running sum of its own steps.
    steps = np.linalg.norm(joint_difference(points[1:], points[:-1], periodic), axis=1)
    arc, length = [], []
    start = 0
    for q, loop in curves:
        arc.append(np.concatenate([[0.0], np.cumsum(steps[start : start + len(q) - 1])]))
        closing = np.linalg.norm(joint_difference(q[0], q[-1], periodic)) if loop else 0.0
        length.append(arc[-1][-1] + float(closing))
        start += len(q)
    curve = np.repeat(np.arange(len(curves)), [len(q) for q, _ in curves])  # (P,)
    s = np.concatenate(arc)  # (P,) arc position along its curve
    total = np.asarray(length)[curve]  # (P,)
    closed = np.array([closed for _, closed in curves])[curve]

    def apart(a: IntArray, b: IntArray) -> FloatArray:  # arc between points of one curve
        d = np.abs(s[a] - s[b])
        return np.where(closed[a], np.minimum(d, total[a] - d), d)

    # Groups of STRAND_GROUP consecutive points of a curve: members (G, STRAND_GROUP),
    # -1 past a curve's end, and each group's middle member, its point in the tree.
    index = np.concatenate([np.arange(len(q)) for q, _ in curves])  # (P,) within its curve
    first = index % STRAND_GROUP == 0  # (P,) a group starts here
    starts = np.flatnonzero(first)  # (G,)
    group = np.cumsum(first) - 1  # (P,)
    size = np.bincount(group)  # (G,) 1 to STRAND_GROUP
    members = starts[:, None] + np.arange(STRAND_GROUP)  # (G, STRAND_GROUP)
    members[np.arange(STRAND_GROUP) >= size[:, None]] = -1
    middle = starts + np.minimum(1, size - 1)  # (G,)
    delta = float(np.abs(s - s[middle[group]]).max())
    embedded = np.concatenate(  # (P, n + periodic joints)
        [points[:, ~periodic], np.cos(points[:, periodic]), np.sin(points[:, periodic])], axis=1
    )
    strand_arc = STRAND_ARC_FACTOR * within_rad
    if delta >= within_rad:  # steps too long for groups to help: every point in the tree
        pairs = cKDTree(embedded).query_pairs(r=within_rad, output_type="ndarray")  # (K, 2)
        a, b = pairs[:, 0], pairs[:, 1]
    else:
        pairs = cKDTree(embedded[middle]).query_pairs(
            r=within_rad + 2.0 * delta, output_type="ndarray"
        )  # (K, 2) groups
        ga, gb = middle[pairs[:, 0]], middle[pairs[:, 1]]
        # No point of either group can be a strand of the other's: one curve, too near.
        same = (curve[ga] == curve[gb]) & (apart(ga, gb) <= strand_arc - 2.0 * delta)
        pairs = pairs[~same]
        a = np.repeat(members[pairs[:, 0]], STRAND_GROUP, axis=1).ravel()  # (9K,)
        b = np.tile(members[pairs[:, 1]], STRAND_GROUP).ravel()
        a, b = a[(a >= 0) & (b >= 0)], b[(a >= 0) & (b >= 0)]
    if not len(a):
        return np.inf
    distance = np.linalg.norm(joint_difference(points[a], points[b], periodic), axis=1)
    strands = (curve[a] != curve[b]) | (apart(a, b) > strand_arc)
    close = strands & (distance <= within_rad)
    return float(distance[close].min()) if close.any() else np.inf


def test_closest_strands_is_the_numpy_kd_tree_answer_to_the_bit() -> None:
    """Random walks as traced curves (open and closed, 3 and 7 joints, some periodic), at
    meeting distances from 0.05 to 0.5 rad: the compiled sweep finds the same least
    distance between two strands as the numpy steps on a KD-tree, bitwise (inf alike)."""
    rng = np.random.default_rng(10)
    found = 0
    for _ in range(200):
        n = int(rng.choice([3, 7]))
        limits = JointLimits(np.full(n, -3.0), np.full(n, 3.0), rng.uniform(size=n) < 0.3)
        curves = [
            (rng.uniform(-3, 3, n) + np.cumsum(rng.normal(0, 0.04, (size, n)), axis=0), loop)
            for size, loop in zip(
                rng.integers(2, 200, rng.integers(1, 5)), rng.uniform(size=4) < 0.5, strict=False
            )
        ]
        within = float(rng.uniform(0.05, 0.5))
        compiled = closest_strands_rad(curves, limits, within)
        assert compiled == numpy_closest_strands_rad(curves, limits, within)
        found += bool(np.isfinite(compiled))
    assert 20 < found < 200


def test_closest_strands_refuses_curve_bounds_that_do_not_cover_the_points() -> None:
    with pytest.raises(ValueError, match="first must rise"):
        native.closest_strands(np.zeros((4, 3)), np.array([0, 3]), np.array([True]),
                               np.zeros(3, bool), 0.1, 0.4)  # fmt: skip
