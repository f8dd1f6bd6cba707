"""Fibres of the bundled models for the connect-stage tests, the spaces the stages move
in on them, and exact points on them."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from service.models.chain import SerialChainKinematics
from service.models.registry import ServedModel
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.collision.scene import Obstacle, Scene
from service.pipeline.fibre import Fibre
from service.pipeline.joint_space import JointLimits, joint_distance
from service.pipeline.run import collision_of, correct_samples, encode, sample, space_of
from service.pipeline.space import FibreSpace
from service.pipeline.targets import Target
from service.pipeline.types import CoaxialSet, Query, Tolerance
from tests.support.numpy_kernels import NumpyStepsKinematics
from training.evaluate.references.planar3r import closed_form_smm
from training.evaluate.targets import uniform_configurations
from training.evaluate.walks import null_space_walk, pose_fibre

__all__ = ["null_space_walk", "pose_fibre"]  # known walks, shared with tools/

TOLERANCE = Tolerance(position_m=1e-6, orientation_rad=1e-6)  # the bundled manifests' query default


def fibre_space(
    fibre: Fibre,
    limits: JointLimits,
    coaxial_sets: tuple[CoaxialSet, ...],
    tolerance: Tolerance = TOLERANCE,
) -> FibreSpace:
    """The space on `fibre` inside `limits`: a walk in it may cross the given coaxial sets
    only where the fibre reaches them (none: `()`)."""
    return FibreSpace(
        fibre=fibre,
        limits=limits,
        coaxial_sets=coaxial_sets,
        tolerance=tolerance,
        collision=CollisionCheck.none(),
    )


def planar_fibre(model: ServedModel, target_m: np.ndarray) -> Fibre:
    manifest = model.manifest
    target = Target(position_m=target_m, rotation=None, condition=np.zeros(1, np.float32))
    return Fibre(target=target, task=manifest.task, kinematics=model.kinematics, damping=1e-3)


def ordered_planar_loop(target_m: np.ndarray, every_rad: float) -> np.ndarray:
    """(k, 3) the one loop of a planar 3R target opposite phi = 0 (so that each elbow
    branch of the closed form is one run of phi) in order along it: the elbow-up branch,
    then the elbow-down branch backwards, thinned to points about `every_rad` apart."""
    (loop,) = closed_form_smm(target_m, phi_step_rad=1e-4)
    half = len(loop) // 2
    ordered = np.concatenate([loop[:half], loop[half:][::-1]])
    periodic = np.ones(3, dtype=bool)
    steps = joint_distance(ordered[1:], ordered[:-1], periodic)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    return ordered[np.unique(np.searchsorted(arc, np.arange(0.0, arc[-1], every_rad)))]


def bump_of(loop: np.ndarray) -> tuple[int, int, int, int]:
    """(joint, before, peak, after): a local maximum of a joint along the loop, inside
    (-3, 3), with the joint 0.05 rad lower at `before` and `after` within 400 points."""
    for joint in range(3):
        q = loop[:, joint]
        for peak in range(400, len(q) - 400):
            window = q[peak - 400 : peak + 401]
            if abs(q[peak]) < 3.0 and q[peak] == window.max() and np.ptp(window) < 1.0:
                before = peak - int(np.argmax(q[peak::-1] < q[peak] - 0.05))
                after = peak + int(np.argmax(q[peak:] < q[peak] - 0.05))
                if before < peak < after:
                    return joint, before, peak, after
    raise AssertionError("no bump found")


@dataclass(frozen=True)
class ServedSpace:
    """A position target's space as the service builds it (self-collision and coaxial sets
    included, a scene's obstacles where asked), the same space behind a plain callable
    (whose steps are numpy's: the reference the compiled walks are pinned to), and valid
    nodes on it."""

    compiled: FibreSpace
    numpy: FibreSpace
    nodes_rad: np.ndarray  # (K, n) accepted samples


def obstacle_scene() -> Scene:
    """Obstacles of every shape about an arm's base, within its reach: a scene the walks
    of a position target run into."""
    half_turn_x = (np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0)
    return Scene((
        Obstacle.of(0, "box", [0.3, 0.2, 0.4], [0.5, 0.1, 0.4], None),
        Obstacle.of(1, "sphere", [0.15], [-0.3, 0.4, 0.6], None),
        Obstacle.of(2, "cylinder", [0.5, 0.08], [0.0, -0.5, 0.5], half_turn_x),
        Obstacle.of(3, "capsule", [0.4, 0.06], [-0.4, -0.3, 0.3], half_turn_x),
        Obstacle.of(4, "box", [1.2, 1.2, 0.05], [0.0, 0.0, -0.2], None),  # a table below
    ))  # fmt: skip


def served_position_spaces(
    model: ServedModel, targets: int, seed: int, scene: Scene | None = None
) -> list[ServedSpace]:
    """`targets` uniform position targets of `model` (FK of configurations in the limits),
    each with the accepted samples of a 300-sample answer; with `scene`, its obstacles
    clear of the target checked too and the samples free of them."""
    spaces = []
    for i, q_target in enumerate(uniform_configurations(model.limits, targets, seed=seed)):
        fk = model.kinematics(q_target[None])
        query = Query.for_model(
            model.manifest, position_m=fk.position_m[0].tolist(), num_samples=300, seed=i
        )
        target = encode(model, query)
        space = space_of(model, target, query.tolerance, collision_of(model, query))
        assert space.collision.self_checked and space.compiled() is not None
        correction = correct_samples(model, space, sample(model, query, target))
        chain = space.fibre.kinematics
        assert isinstance(chain, SerialChainKinematics)
        if scene is not None:  # the obstacles clear of the target by a hand's width
            clear = tuple(
                o for o in scene.obstacles if o.signed_distance_m(fk.position_m[0]) > 0.15
            )
            space = replace(space, collision=replace(space.collision, scene=Scene(clear)))
        numpy = replace(space, fibre=replace(space.fibre, kinematics=NumpyStepsKinematics(chain)))
        assert numpy.compiled() is None
        nodes = correction.q_rad[space.accept(correction).on_fibre]
        nodes = nodes[space.valid(nodes)]
        spaces.append(ServedSpace(space, numpy, nodes))
    return spaces
