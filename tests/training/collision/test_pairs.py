"""training.collision.pairs (and build's use of it): the pairs never checked, MoveIt's way.

On the small arm: the adjacent pairs are the joints' (through mid and l4, which have no
geometry, as the arm's module lists them); the world slab that l1 sweeps into for every
j1 above ~0.04 rad of [0, 2.8] (free at j1 = 0, the default) is found "always"; on the
build's configurations (seeded, uniform in the limits) coal finds every "never" pair
free and every pair left checked touching sometimes but under 95 % of the time; pairs
touching at the default configuration are "default", and the default configuration is
MoveIt's (0, or mid-range where 0 is outside the limits). With an SRDF its
disable_collisions are read (pairs naming links that are not bodies left out) and
nothing is sampled.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from service.manifest import ChainSpec, JointSpec
from service.pipeline.joint_space import JointLimits
from tests.support.collision_arm import ADJACENT, write_srdf
from training.collision.build import build_collision_model
from training.collision.geometry import read_bodies
from training.collision.pairs import adjacent_pairs, default_configuration, srdf_pairs
from training.evaluate.references.collision import CoalRobot


def test_adjacent_pairs_walk_through_links_without_geometry(
    arm_urdf: Path, arm_chain: ChainSpec
) -> None:
    """The arm's adjacent pairs, exactly."""
    assert set(adjacent_pairs(arm_urdf, read_bodies(arm_urdf, arm_chain))) == ADJACENT


def test_sampled_pairs_find_always_never_and_default(
    arm_urdf: Path, arm_chain: ChainSpec, arm_joints: JointSpec
) -> None:
    """world-l1 is 'always'; 'never' pairs are free in every sampled configuration, the
    checked ones touch in some but not 95 %; a 'default' pair touches at the default."""
    built = build_collision_model(arm_urdf, arm_chain, arm_joints, configurations=400, seed=1)
    assert built is not None
    reasons = {pair.links: pair.reason for pair in built.spec.disabled_pairs}
    assert reasons[("l1", "world")] == "always"
    assert {links for links, reason in reasons.items() if reason == "adjacent"} == ADJACENT
    bodies = read_bodies(arm_urdf, arm_chain)
    robot = CoalRobot(arm_chain, bodies)
    index = {name: i for i, name in enumerate(robot.names)}
    limits = JointLimits.of(arm_joints)
    q = np.random.default_rng(1).uniform(limits.lower_rad, limits.upper_rad, size=(400, 4))
    never = [(index[a], index[b]) for (a, b), r in reasons.items() if r == "never"]
    assert never and not robot.pair_collisions(q, never).any()
    default = [(index[a], index[b]) for (a, b), r in reasons.items() if r == "default"]
    assert robot.pair_collisions(default_configuration(arm_joints), default).all()
    checked = robot.checked_pairs(reasons)
    share = robot.pair_collisions(q, checked).mean(axis=0)
    assert checked and np.all((share > 0) & (share < 0.95))


def test_the_default_configuration_is_zero_or_mid_range() -> None:
    """0 where the limits hold it, (lower + upper) / 2 where they do not."""
    joints = JointSpec(
        names=["a", "b", "c"], lower_rad=[-1.0, 0.5, -3.0], upper_rad=[1.0, 2.5, -0.1],
        periodic=[False, False, False],
    )  # fmt: skip
    np.testing.assert_array_equal(default_configuration(joints), [[0.0, 1.5, -1.55]])


def test_an_srdf_gives_its_pairs_and_nothing_is_sampled(
    tmp_path: Path, arm_urdf: Path, arm_chain: ChainSpec, arm_joints: JointSpec
) -> None:
    """The SRDF's disable_collisions between bodies become 'srdf' pairs (one naming mid,
    a link without geometry, is left out; one that is adjacent stays 'adjacent'), and
    there are no sampled reasons."""
    srdf = write_srdf(tmp_path, [("l1", "world"), ("l3", "base"), ("mid", "l1"), ("l1", "l2")])
    bodies = read_bodies(arm_urdf, arm_chain)
    assert srdf_pairs(srdf, bodies) == [("base", "l3"), ("l1", "l2"), ("l1", "world")]
    built = build_collision_model(arm_urdf, arm_chain, arm_joints, srdf, configurations=50)
    assert built is not None
    reasons = {pair.links: pair.reason for pair in built.spec.disabled_pairs}
    assert {links for links, r in reasons.items() if r == "srdf"} == {
        ("base", "l3"), ("l1", "world"),
    }  # fmt: skip
    assert set(reasons.values()) == {"adjacent", "srdf"}
