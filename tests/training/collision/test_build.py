"""training.collision.build: collision.json's content and its free space lost, re-measured.

On the small arm, with the sampled pairs: every body is covered within the budget (the
sphere count is the spheres written), and the free space lost is what the test measures
itself on the build's configurations (seeded, uniform in the limits): of those coal
finds free over the pairs not disabled, the fraction the service's check calls colliding;
that check never calls free what coal calls colliding, and loses no more than the spheres
alone. A URDF whose chain has no collision geometry (only visuals) has no collision model.
Importing the training command (and this module with it) does not import coal: a machine
that only trains needs coal only where a collision model is built.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from service.manifest import ChainSpec, JointSpec
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.collision.robot import RobotSpheres
from service.pipeline.collision.scene import Scene
from service.pipeline.joint_space import JointLimits
from tests.support.small_arm import write_arm
from training.collision.build import build_collision_model
from training.collision.geometry import read_bodies
from training.evaluate.references.collision import CoalRobot
from training.kinematics import chain_spec, joint_spec, load_chain


def test_free_space_lost_is_the_checks_false_alarms_among_coal_free_configurations(
    arm_urdf: Path, arm_chain: ChainSpec, arm_joints: JointSpec
) -> None:
    """The build's figure equals the test's own count on the same configurations."""
    built = build_collision_model(
        arm_urdf, arm_chain, arm_joints, spheres_per_body=3, configurations=300, seed=4
    )
    assert built is not None and built.configurations_sampled == 300
    assert all(len(body.radii_m) <= 3 for body in built.spec.bodies)
    assert built.sphere_count == sum(len(body.radii_m) for body in built.spec.bodies)
    limits = JointLimits.of(arm_joints)
    q = np.random.default_rng(4).uniform(limits.lower_rad, limits.upper_rad, size=(300, 4))
    disabled = [pair.links for pair in built.spec.disabled_pairs]
    coal_free = ~CoalRobot(arm_chain, read_bodies(arm_urdf, arm_chain)).in_self_collision(
        q, disabled
    )
    spheres = RobotSpheres.of(arm_chain, built.spec)
    check_free = CollisionCheck(spheres, Scene(), True, 0.0).free(q)
    spheres_free = spheres.self_clearance_m(spheres.place(q)) >= 0
    assert coal_free.sum() > 0 and not (check_free & ~coal_free).any()
    assert (spheres_free <= check_free).all()
    assert built.free_space_lost_fraction == (~check_free & coal_free).sum() / coal_free.sum()


def test_a_urdf_without_collision_geometry_has_no_collision_model(tmp_path: Path) -> None:
    """The small arm of the training tests has visuals only: None."""
    urdf = write_arm(tmp_path)
    chain = load_chain(urdf, "tool", "base")
    assert build_collision_model(urdf, chain_spec(chain), joint_spec(chain)) is None


def test_the_training_command_imports_without_coal() -> None:
    imported = subprocess.run(
        [sys.executable, "-c", "import sys, training.cli, training.collision.build; "
         "print('coal' in sys.modules)"],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    assert imported.stdout.strip() == "False"
