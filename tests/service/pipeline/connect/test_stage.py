"""connectivity (stage 5): components decided on the fibre. r = 1: every curve traced whole,
cut by the limits, ordered paths that are exact, inside the limits and finely spaced,
checked against the closed forms (planar 3R) and the S-R-S IK components (iiwa pose),
also where twin curves run a few hundredths of a radian apart and where one piece was
traced twice; where twins run closer than the trace can resolve (the planar 3R within
1e-4 of rho = 1) the answer says near_singular; the answer is the same on one thread and
on two (where sigma_min and the strands' closest approach run beside the rest); a traced
loop is cut only where a step is longer than a continuation step (2 h); r > 1: the
roadmap joins one component across sampling gaps and keeps two apart."""

import dataclasses

import numpy as np
import pytest

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.connect.curves import exact_paths
from service.pipeline.connect.trace import TracedPiece
from service.pipeline.joint_space import JointLimits, joint_distance
from service.pipeline.run import run
from service.pipeline.types import Query, SmmResult, Tolerance
from tests.service.pipeline.fibre_support import fibre_space, ordered_planar_loop, planar_fibre
from training.evaluate.references.iiwa14 import dh_pose, pose_smm
from training.evaluate.references.planar3r import planar3r_position
from training.evaluate.served import orientation_wxyz
from training.evaluate.targets import dh_targets

SPACING_RAD = 0.05


@pytest.fixture(scope="module")
def iiwa14_pose() -> ServedModel:
    return load_model(REPO_MODELS_DIR / "iiwa14-pose", threads=1)


def check_paths(result: SmmResult, limits: JointLimits) -> None:
    """Every component has a path: in the limits, spaced <= 0.05 rad, closed or at limits.

    Next to a singular point (the answer says near_singular) a point Newton cannot make
    exact is left out, so a gap there may reach twice the tracing step (0.3 rad), and a
    path is cut where the trace could not show the fibre joins two points, so an open
    end may lie off the limits.
    """
    lower, upper, periodic = limits.lower_rad, limits.upper_rad, limits.periodic
    spacing = 0.3 if result.structure.near_singular else SPACING_RAD
    for component in result.components:
        path = component.path
        assert path is not None and len(path.q_rad) >= 1
        q = path.q_rad
        assert np.all(periodic | ((q >= lower) & (q <= upper)))
        gaps = joint_distance(q[1:], q[:-1], periodic)
        if path.closed:
            gaps = np.append(gaps, joint_distance(q[-1], q[0], periodic))
        elif not result.structure.near_singular:
            # An open component ends at the joint limits: some joint sits on a limit there.
            for end in (q[0], q[-1]):
                slack = np.minimum(end - lower, upper - end)[~periodic]
                assert slack.min() <= 1e-9
        assert gaps.max(initial=0.0) <= spacing
        assert path.arc_length_rad == pytest.approx(gaps.sum())


@pytest.mark.parametrize(("rho", "loops"), [(0.5, 2), (0.999, 2), (1.0005, 1), (2.0, 1)])
def test_planar_components_follow_the_closed_form(
    planar3r: ServedModel, rho: float, loops: int
) -> None:
    """Two loops inside rho = 1, even 0.999 where they pass 0.1 rad apart; one beyond.

    Next to the singular circle (0.999, 1.0005) the two loops pass within a meeting
    distance of each other and the trace may join or part them wrongly: there an answer
    either has the closed form's count and closed loops or says its structure is
    ambiguous (`near_singular`), and most seeds have the count right; away from it every
    seed does.
    """
    target = rho * np.array([np.cos(0.4), np.sin(0.4)])
    pinched = abs(rho - 1.0) < 0.01
    right = 0
    for seed in range(5):
        query = Query.for_model(
            planar3r.manifest, position_m=target.tolist(), num_samples=600, seed=seed
        )
        result = run(planar3r, query)
        right += len(result.components) == loops
        ambiguous = pinched and result.structure.near_singular
        assert len(result.components) == loops or ambiguous
        check_paths(result, planar3r.limits)
        for component in result.components:
            # No limits on the planar arm: every component is a loop, or a piece whose
            # trace stopped next to the singular circle.
            assert component.closed or ambiguous
            reached = planar3r_position(component.path.q_rad)  # type: ignore[union-attr]
            assert np.abs(reached - target).max() <= 1e-6
    assert right >= 3


@pytest.mark.parametrize("angle", [0.3, 2.0])
@pytest.mark.parametrize("rho", [0.9999, 0.99999, 1.00001, 1.0001])
def test_planar_twins_closer_than_the_trace_resolves_are_flagged(
    planar3r: ServedModel, rho: float, angle: float
) -> None:
    """Within 1e-4 of rho = 1 the wrist passes within 1e-4 m of the base, and the fibre's
    two elbow branches run as twin strands far closer than the fronts' meeting distance
    while sigma_min(J) stays near 0.005-0.02: the structure (2 loops inside, 1 beyond) is
    not resolved there, and the answer must say so; its paths are exact all the same."""
    target = rho * np.array([np.cos(angle), np.sin(angle)])
    query = Query.for_model(planar3r.manifest, position_m=target.tolist(), seed=1)
    result = run(planar3r, query)
    assert result.structure.near_singular
    for component in result.components:
        reached = planar3r_position(component.path.q_rad)  # type: ignore[union-attr]
        assert np.abs(reached - target).max() <= 1e-6


def _same_answer(one: SmmResult, two: SmmResult) -> None:
    assert one.structure == two.structure and one.counts == two.counts
    assert len(one.components) == len(two.components)
    for a, b in zip(one.components, two.components, strict=True):
        np.testing.assert_array_equal(a.configurations_rad, b.configurations_rad)
        assert (a.path is None) == (b.path is None) and a.clearance_m == b.clearance_m
        if a.path is not None and b.path is not None:
            np.testing.assert_array_equal(a.path.q_rad, b.path.q_rad)


def test_the_answer_is_the_same_on_one_thread_and_two(
    iiwa14_pose: ServedModel, planar3r: ServedModel
) -> None:
    """The least sigma_min and the strands' closest approach run on a thread of their own
    beside the trace and the free pieces when there are two: the same answers, flags and
    all, as one thread gives. On these two targets (a planar 3R just outside rho = 1, an
    iiwa14 pose with the elbow 0.04 rad from straight and self-collision checked) two
    strands pass closer than the trace resolves while sigma_min stays above 0.005: only
    the strands' closest approach flags them near_singular."""
    manifest = iiwa14_pose.manifest
    q_target = np.array(
        [-0.5664007844289922, -1.262865606030502, -2.4285203146198207, -0.03995694610587773,
         -1.1945611949644335, 0.720450460057029, -1.8355556989518227]
    )  # fmt: skip
    fk = iiwa14_pose.kinematics(q_target[None])
    elbow = Query.for_model(
        manifest, position_m=fk.position_m[0].tolist(),
        orientation_wxyz=orientation_wxyz(fk.rotation[0]), seed=7, check_self=True,
    )  # fmt: skip
    angle = -2.5998599473973916
    twins = Query.for_model(
        planar3r.manifest,
        position_m=(1.003341579814633 * np.array([np.cos(angle), np.sin(angle)])).tolist(),
        seed=47,
    )
    for model, query in ((planar3r, twins), (iiwa14_pose, elbow)):
        one = run(dataclasses.replace(model, row_threads=1), query)
        two = run(dataclasses.replace(model, row_threads=2), query)
        _same_answer(one, two)
        sigma = two.structure.min_singular_value
        assert two.structure.near_singular and sigma is not None and sigma > 0.005


@pytest.mark.parametrize("seed", [3, 4, 5, 6])
def test_iiwa_pose_components_match_the_srs_ik(iiwa14_pose: ServedModel, seed: int) -> None:
    """Count and membership against the exact S-R-S components; paths exact by the DH table."""
    manifest = iiwa14_pose.manifest
    limits = JointLimits.of(manifest.joints)
    q_target = np.random.default_rng(seed).uniform(0.8 * limits.lower_rad, 0.8 * limits.upper_rad)
    fk = iiwa14_pose.kinematics(q_target[None])
    position, rotation = fk.position_m[0], fk.rotation[0]
    query = Query.for_model(
        manifest, position_m=position.tolist(), orientation_wxyz=orientation_wxyz(rotation),
        num_samples=1000, seed=seed,
    )  # fmt: skip
    result = run(iiwa14_pose, query)
    exact = pose_smm(position, rotation)
    if result.structure.near_singular:
        pytest.skip("near-singular target: the structure may be ambiguous (flagged)")
    assert len(result.components) == len(exact)
    # Each returned component lies on exactly one exact component, and each exact one is hit.
    points = np.concatenate([c.q_rad for c in exact])
    owner = np.concatenate([np.full(len(c.q_rad), i) for i, c in enumerate(exact)])
    hit = set()
    for component in result.components:
        q = component.path.q_rad  # type: ignore[union-attr]
        nearest = np.argmin(np.linalg.norm(q[:, None, :] - points[None, ::4, :], axis=2), axis=1)
        labels = set(owner[::4][nearest].tolist())
        assert len(labels) == 1
        hit |= labels
        pose = dh_pose(q)  # the paper's DH table: independent of the URDF and ONNX
        assert np.abs(pose[:, :3, 3] - position).max() <= 1e-6
    assert hit == set(range(len(exact)))
    check_paths(result, limits)


@pytest.mark.parametrize("q4_rad", [0.015, 0.03])
def test_twins_a_few_hundredths_apart_stay_apart(iiwa14_pose: ServedModel, q4_rad: float) -> None:
    """With the elbow nearly straight (|q4| small), the fibre's curves run in parallel pairs,
    q4 = +-|q4| on the whole fibre (the elbow angle is fixed by the shoulder-wrist
    distance), a few hundredths of a radian apart: flagged near-singular, yet no component
    holds both twins and the count is the S-R-S count."""
    manifest = iiwa14_pose.manifest
    q_target = np.array([-0.34, -1.259, 1.261, q4_rad, 2.189, 1.661, -1.119])
    fk = iiwa14_pose.kinematics(q_target[None])
    position, rotation = fk.position_m[0], fk.rotation[0]
    query = Query.for_model(
        manifest, position_m=position.tolist(), orientation_wxyz=orientation_wxyz(rotation),
        num_samples=1000, seed=1,
    )  # fmt: skip
    result = run(iiwa14_pose, query)
    exact = pose_smm(position, rotation)
    assert all(np.ptp(c.q_rad[:, 3]) < 1e-9 for c in exact)  # q4 is constant on each
    for component in result.components:
        q = np.concatenate([component.configurations_rad, component.path.q_rad])  # type: ignore[union-attr]
        assert np.all(np.sign(q[:, 3]) == np.sign(q[0, 3]))
        # On the fibre (within 1e-6 m, where sigma_min is ~0.4 |q4|, so q4 itself within ~1e-4)
        assert np.abs(np.abs(q[:, 3]) - q4_rad).max() < 0.1 * q4_rad
    assert len(result.components) == len(exact)


def test_a_piece_traced_twice_is_returned_once(iiwa14_pose: ServedModel) -> None:
    """On this pose (the DH check's target 13) two chains of fronts once covered the same
    four pieces, each returned twice with the samples split between the copies: every
    piece comes once, and the count is the S-R-S count."""
    pose = dh_targets(200, 3).pose[13]
    query = Query.for_model(
        iiwa14_pose.manifest, position_m=pose[:3, 3].tolist(),
        orientation_wxyz=orientation_wxyz(pose[:3, :3]), num_samples=1000, seed=13,
    )  # fmt: skip
    result = run(iiwa14_pose, query)
    assert not result.structure.near_singular
    assert len(result.components) == len(pose_smm(pose[:3, 3], pose[:3, :3]))
    ends = [c.path.q_rad[[0, -1]] for c in result.components]  # type: ignore[union-attr]
    for i in range(len(ends)):
        for j in range(i):
            assert (
                min(np.abs(ends[i] - ends[j]).max(), np.abs(ends[i] - ends[j][::-1]).max()) > 1e-3
            )


@pytest.mark.parametrize(
    ("removed", "pieces", "closed"), [(0, 1, True), (4, 1, True), (12, 1, False)]
)
def test_a_loop_is_cut_only_where_a_step_is_longer_than_a_continuation_step(
    planar3r: ServedModel, removed: int, pieces: int, closed: bool
) -> None:
    """A traced loop with points left out: a gap under 2 h (0.3 rad) is a step the trace
    checked and the loop stays one closed path (not whole: flagged); a longer gap shows
    nothing, and the loop opens there into one path that starts just after it."""
    target = np.array([-1.5, -0.1])
    q = ordered_planar_loop(target, every_rad=0.03)
    error = planar3r_position(q) - target
    keep = np.ones(len(q), dtype=bool)
    keep[50 : 50 + removed] = False
    piece = TracedPiece(path_rad=q[keep], error=error[keep], closed=True)
    limits = JointLimits(np.full(3, -np.pi), np.full(3, np.pi), np.ones(3, dtype=bool))
    tolerance = Tolerance(position_m=1e-6, orientation_rad=1e-6)
    space = fibre_space(planar_fibre(planar3r, target), limits, (), tolerance)
    paths, whole = exact_paths(piece, space, SPACING_RAD, 0.3)
    assert len(paths) == 1 and paths[0].closed == closed
    assert whole == (removed == 0)
    if not closed:
        np.testing.assert_array_equal(paths[0].q_rad[0], q[50 + removed])
        np.testing.assert_array_equal(paths[0].q_rad[-1], q[49])
    assert len(paths[0].q_rad) == keep.sum()
