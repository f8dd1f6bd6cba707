"""roadmap (stage 5 for r > 1): on the iiwa14's 4-D position fibre, a null-space random walk
along one component comes back as one component, and the elbow-up and elbow-down
components, nearer each other than the 2.5 rad radius the service used to join samples
with, stay two; two samples joined only through the shoulder set (q2 = 0, where q1 + q3
is all that moves the arm) are one component once the roadmap has its coaxial nodes or
its steering walks, and two without either;
and where the link lengths keep the fibre off the shoulder and elbow sets, no component
holds both signs of q2 or of q4. Each component keeps its graph: an added node polished
onto the fibre stays in it, one left invalid leaves with its edges. The links tried
between components left apart are, per
pair of components, the shortest of every node's nearest node in each other component
(brute force on the joint metric), lone nodes included. The components kept up to date
as edges and nodes come are scipy's over every edge so far."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.connect import planner_settings, roadmap_settings
from service.pipeline.connect.roadmap import Roadmap, roadmap_components
from service.pipeline.deadline import NO_DEADLINE
from service.pipeline.fibre import project
from service.pipeline.joint_space import JointLimits, joint_distance
from service.pipeline.run import run
from service.pipeline.types import CoaxialSet, Query
from tests.service.pipeline.fibre_support import fibre_space, null_space_walk, pose_fibre
from training.evaluate.references.iiwa14 import dh_pose as iiwa14_pose

OLD_RADIUS_RAD = 2.5  # the radius graph's default for this model before stage 5


@pytest.fixture(scope="module")
def iiwa14_position() -> ServedModel:
    return load_model(REPO_MODELS_DIR / "iiwa14-position", threads=1)


def test_a_random_walk_along_one_component_is_one_component(
    iiwa14_position: ServedModel,
) -> None:
    q0 = np.array([0.3, 0.5, -0.4, -1.3, 0.6, 0.9, 0.2])
    walk = null_space_walk(iiwa14_position, q0, steps=400, seed=0)
    travelled = np.linalg.norm(walk[-1] - walk[0])
    assert len(walk) > 300 and travelled > 1.0
    # It crosses the wrist singular set (q6 = 0), where sparse samples come back split.
    assert walk[:, 5].min() < 0.0 < walk[:, 5].max()
    nodes = walk[::6][np.random.default_rng(1).permutation(len(walk[::6]))]  # ~0.3 rad apart
    spec = iiwa14_position.manifest.defaults.connectivity
    limits = iiwa14_position.limits
    space = fibre_space(pose_fibre(iiwa14_position, q0), limits, ())
    labels = roadmap_components(space, nodes, planner_settings(spec), roadmap_settings(spec)).labels
    assert set(labels.tolist()) == {0}


def test_elbow_up_and_down_stay_two_though_nearer_than_the_old_radius(
    iiwa14_position: ServedModel,
) -> None:
    # The target is 0.674 m from the shoulder; with the elbow straight (q4 = 0) the end
    # effector is 0.82 +- 0.126 m from it, so q4 never reaches 0 on this fibre: the
    # elbow-up and elbow-down samples lie on different components.
    position = [0.544, 0.136, 0.734]
    query = Query.for_model(iiwa14_position.manifest, position_m=position, num_samples=600, seed=3)
    result = run(iiwa14_position, query)
    components = [c.configurations_rad for c in result.components if c.size >= 20]
    elbow = [np.sign(c[:, 3]) for c in components]
    assert all(len(set(side.tolist())) == 1 for side in elbow)  # no component mixes them
    up = np.concatenate([c for c, s in zip(components, elbow, strict=True) if s[0] > 0])
    down = np.concatenate([c for c, s in zip(components, elbow, strict=True) if s[0] < 0])
    nearest = np.min(np.linalg.norm(up[:, None, :] - down[None, :, :], axis=2))
    assert nearest < OLD_RADIUS_RAD  # a radius graph would have joined them


def walk_holding(model: ServedModel, q0: np.ndarray, joint: int, to_rad: float) -> np.ndarray:
    """q0 (7,) walked along its position fibre to q[joint] = to_rad in 0.02 rad steps, that
    joint held while Newton puts the others back; every step is checked to converge."""
    fibre = pose_fibre(model, q0)
    q = q0.copy()
    locked = np.zeros((1, 7), dtype=bool)
    locked[0, joint] = True
    for value in np.linspace(q0[joint], to_rad, 40)[1:]:
        guess = q.copy()
        guess[joint] = value
        projected = project(fibre, guess[None], 4, locked=locked)
        assert projected.error_norm[0] < 1e-10
        assert np.linalg.norm(projected.q_rad[0] - q) < 0.2  # no jump
        q = projected.q_rad[0]
    return q


def test_samples_joined_only_through_the_shoulder_set_are_one_component(
    iiwa14_position: ServedModel,
) -> None:
    limits = iiwa14_position.limits
    on_set = np.array([-0.3, 0.0, 0.4, 1.0, -0.5, 1.2, 0.0])  # q2 = 0
    slid = on_set + 2.4 * np.array([1.0, 0, -1.0, 0, 0, 0, 0])  # the set's self-motion
    # By the DH table (independent of the service): the slide keeps the position.
    np.testing.assert_allclose(iiwa14_pose(slid[None]), iiwa14_pose(on_set[None]), atol=1e-12)
    a = walk_holding(iiwa14_position, on_set, joint=1, to_rad=0.35)
    b = walk_holding(iiwa14_position, slid, joint=1, to_rad=-0.35)
    for q in (a, b):
        assert np.all((q >= limits.lower_rad) & (q <= limits.upper_rad))
        np.testing.assert_allclose(
            iiwa14_pose(q[None])[0, :3, 3], iiwa14_pose(on_set[None])[0, :3, 3], atol=1e-9
        )
    spec = iiwa14_position.manifest.defaults.connectivity
    # Farther apart than any candidate edge of the roadmap (bridges reach 3 rad) ...
    assert np.linalg.norm(a - b) > spec.bridge_radius_rad
    fibre = pose_fibre(iiwa14_position, on_set)

    def labels(coaxial: tuple[CoaxialSet, ...], steer_pairs: int) -> list[int]:
        settings = replace(roadmap_settings(spec), steer_pairs=steer_pairs)
        space = fibre_space(fibre, limits, coaxial)
        return roadmap_components(
            space, np.stack([a, b]), planner_settings(spec), settings
        ).labels.tolist()

    assert labels((), steer_pairs=0) == [0, 1]
    # ... but joined through the set's line of nodes, or by a walk steered along the fibre.
    assert labels(tuple(iiwa14_position.coaxial_sets), steer_pairs=0) == [0, 0]
    assert labels((), steer_pairs=roadmap_settings(spec).steer_pairs) == [0, 0]


def test_twins_stay_apart_where_the_fibre_cannot_reach_the_shoulder_or_elbow_set(
    iiwa14_position: ServedModel,
) -> None:
    # The end effector is 0.555 m from the elbow-up point (q2 = 0 allows 0.526) and
    # 0.611 m from the shoulder (q4 = 0 needs at least 0.694): along any path on this
    # fibre q2 and q4 keep their signs, though q2 comes within 0.1 rad of 0.
    q_target = np.array([-1.8321, 0.3116, -2.7316, 1.2636, 2.7301, 1.4829, -2.7446])
    position = iiwa14_pose(q_target[None])[0, :3, 3]
    assert np.linalg.norm(position - np.array([0, 0, 0.78])) > 0.40 + 0.126
    assert np.linalg.norm(position - np.array([0, 0, 0.36])) < 0.82 - 0.126
    query = Query.for_model(
        iiwa14_position.manifest, position_m=position.tolist(), num_samples=1000, seed=29
    )
    result = run(iiwa14_position, query)
    signs = set()
    for component in result.components:
        q = component.configurations_rad
        assert len(set(np.sign(q[:, 1]).tolist())) == 1
        assert len(set(np.sign(q[:, 3]).tolist())) == 1
        signs.add((np.sign(q[0, 1]), np.sign(q[0, 3])))
    assert len(signs) == 4  # all four twins are there, each its own component


def test_the_links_tried_between_components_are_the_shortest_by_brute_force(
    iiwa14_position: ServedModel,
) -> None:
    # Mostly lone nodes, as after the neighbour rounds on a 4-D fibre, and some groups;
    # one periodic joint, so the metric wraps there and only there.
    rng = np.random.default_rng(3)
    q = rng.uniform(-2.0, 2.0, size=(160, 7))
    periodic = np.array([False, False, True, False, False, False, False])
    manifest_limits = iiwa14_position.limits
    limits = JointLimits(manifest_limits.lower_rad, manifest_limits.upper_rad, periodic)
    settings = roadmap_settings(iiwa14_position.manifest.defaults.connectivity)
    space = fibre_space(pose_fibre(iiwa14_position, q[0]), limits, ())
    planner = planner_settings(iiwa14_position.manifest.defaults.connectivity)
    roadmap = Roadmap(space, q, planner, NO_DEADLINE)
    groups = rng.integers(0, 12, size=60)  # nodes 0..59 in 12 groups, 60..159 alone
    for g in range(12):
        members = np.flatnonzero(groups == g)
        roadmap.join(members[:-1], members[1:])
    radius_rad, per_pair = 3.0, 3
    rows, cols = roadmap._nearest_pairs(settings, per_pair, radius_rad, untested_only=False)

    root = roadmap.roots()
    distance = joint_distance(q[:, None], q[None], periodic)  # (N, N)
    links: dict[tuple[int, int], float] = {}  # every node's nearest in every other component
    for label in np.unique(root):
        inside = np.flatnonzero(root == label)
        for o in np.flatnonzero(root != label):
            a = inside[np.argmin(distance[o, inside])]
            if distance[o, a] < radius_rad:
                links[(min(a, o), max(a, o))] = distance[o, a]
    by_pair: dict[tuple[int, int], list[tuple[float, tuple[int, int]]]] = {}
    for (a, b), length in links.items():
        pair = (min(root[a], root[b]), max(root[a], root[b]))
        by_pair.setdefault(pair, []).append((length, (a, b)))
    expected = {link for kept in by_pair.values() for _, link in sorted(kept)[:per_pair]}
    got = {(int(min(a, b)), int(max(a, b))) for a, b in zip(rows, cols, strict=True)}
    assert len(expected) > 100 and got == expected


def test_the_components_kept_up_to_date_are_scipys_over_every_edge(
    iiwa14_position: ServedModel,
) -> None:
    """Edges joined in rounds and nodes appended between them, as the roadmap's stages do:
    after every round `roots` (merged along the new edges only) is the labelling of
    scipy's connected_components over every edge so far, numbers included."""
    rng = np.random.default_rng(5)
    q = rng.uniform(-2.0, 2.0, size=(200, 7))
    limits = iiwa14_position.limits
    space = fibre_space(pose_fibre(iiwa14_position, q[0]), limits, ())
    planner = planner_settings(iiwa14_position.manifest.defaults.connectivity)
    roadmap = Roadmap(space, q, planner, NO_DEADLINE)
    assert roadmap.roots().tolist() == list(range(200))
    for round_ in range(12):
        if round_ % 4 == 3:  # new nodes, as the steering walks' ends and the coaxial lines
            roadmap.q_rad = np.concatenate([roadmap.q_rad, rng.uniform(-2, 2, size=(15, 7))])
        count = len(roadmap.q_rad)
        a, b = rng.integers(count, size=(2, int(rng.integers(0, 25))))
        roadmap.join(a, b)
        every = connected_components(
            coo_matrix(
                (np.ones(sum(len(x) for x in roadmap.joined_from)), (
                    np.concatenate(roadmap.joined_from), np.concatenate(roadmap.joined_to)
                )),
                shape=(count, count),
            ),
            directed=False,
        )[1]  # fmt: skip
        assert roadmap.roots().tolist() == every.tolist()
    assert 1 < len(np.unique(roadmap.roots())) < len(roadmap.q_rad)


def test_the_graphs_keep_polished_added_nodes_and_drop_the_ones_left_invalid(
    iiwa14_position: ServedModel,
) -> None:
    """Two samples joined only through an added node: polished onto the fibre (from 1e-5
    off, as a walk leaves it) the node stays, exact by the DH table, and both samples are
    one component whose graph is [a, b, node] with edges a-node and b-node; 0.2 rad outside
    the limits (farther than a polish may move a node) it leaves with its edges, and the
    samples are two components of one node each."""
    limits = iiwa14_position.limits
    on_set = np.array([-0.3, 0.0, 0.4, 1.0, -0.5, 1.2, 0.0])
    a = walk_holding(iiwa14_position, on_set, joint=1, to_rad=0.35)
    b = walk_holding(iiwa14_position, on_set, joint=1, to_rad=-0.35)
    spec = iiwa14_position.manifest.defaults.connectivity
    space = fibre_space(pose_fibre(iiwa14_position, on_set), limits, ())
    goal = iiwa14_pose(on_set[None])[0, :3, 3]

    def finished(node: np.ndarray) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
        roadmap = Roadmap(space, np.stack([a, b]), planner_settings(spec), NO_DEADLINE)
        roadmap.q_rad = np.concatenate([roadmap.q_rad, node[None]])
        roadmap.join(np.array([0, 2]), np.array([2, 1]))
        done = roadmap.finished(num_samples=2)
        return done.labels, [g.q_rad for g in done.graphs], [g.edges for g in done.graphs]

    near = on_set + 1e-5 * np.array([1.0, -1.0, 0.5, 0.3, -0.2, 0.1, 0.4])
    labels, nodes, edges = finished(near)
    assert labels.tolist() == [0, 0] and len(nodes) == 1
    np.testing.assert_array_equal(nodes[0][:2], np.stack([a, b]))
    assert np.linalg.norm(iiwa14_pose(nodes[0][2:])[0, :3, 3] - goal) <= 1e-9
    assert np.linalg.norm(nodes[0][2] - near) < 1e-4
    assert edges[0].tolist() == [[0, 2], [1, 2]]
    outside = on_set.copy()
    outside[0] = limits.upper_rad[0] + 0.2
    labels, nodes, edges = finished(outside)
    assert labels.tolist() == [0, 1]
    assert [len(q) for q in nodes] == [1, 1] and [len(e) for e in edges] == [0, 0]
