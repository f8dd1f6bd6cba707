"""The space the pipeline moves in (OMPL's SpaceInformation, for a fibre): the target's
fibre, the joint limits, the chain's coaxial sets, the query's tolerance and its collision
check, with the one question every stage asks of it: is this configuration valid, is this
motion valid.

A configuration is valid when it reaches the target within the tolerance, lies inside
the limits and is free of collision by the query's margin (`accept`). A motion from a
valid configuration to the projection of a step is valid (`motion_valid`) when the
projection converged, lies inside the limits, moved no farther than the step allows (no
jump), does not cross a coaxial set where the fibre does not reach it
(`crossings_on_fibre`: such a step has jumped onto a nearby twin branch), and is free of
collision: a walk's motion is checked at every step it takes, the resolution of the
walk, and with a `LimitCheck` against the limits between a step's ends at a finer one
(`inside_between`). Every stage that keeps configurations or walks between them asks here, so a new
condition on what is valid is added in this module, not in each stage's signature.
`kinematic()` is the same fibre with collisions aside: the r = 1 trace follows each
curve whole there, and the curves are then cut where they enter collision
(connect/free_pieces.py).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from service.pipeline import native
from service.pipeline.acceptance import accept
from service.pipeline.arrays import BoolArray, FloatArray
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.correction import error_norms
from service.pipeline.fibre import Fibre, project
from service.pipeline.joint_space import JointLimits, wrap_to_pi
from service.pipeline.targets import kernel_orientation
from service.pipeline.types import Acceptance, CoaxialSet, Correction, Tolerance

# Newton steps each step of `inside_between`'s fine walk takes onto the fibre at most
# (native.c's LIMIT_CHECK_ITERATIONS is the same).
LIMIT_CHECK_ITERATIONS = 6


@dataclass(frozen=True)
class LimitCheck:
    """How a walk checks a step against the joint limits between its ends (`inside_between`):
    a walk at steps of `spacing_rad` between them, wherever a path `stretch` times the step
    long could reach a limit."""

    spacing_rad: float
    stretch: float  # the walk's lambda: the longest path it takes a step to stand for


# The fibre reaches a coaxial set where Newton, the aligning joint held on it, gets this
# near: the answers' tolerance, not the walks' coarser 1e-4, which counts as reached a set
# the fibre misses by less (an iiwa elbow 0.04 rad from straight on a fibre whose |q4| is
# fixed: its elbow twins would join). native.c's SET_REACH_TOLERANCE is the same.
SET_REACH_TOLERANCE = 1e-6


@dataclass(frozen=True)
class FibreSpace:
    """One target's fibre inside the joint limits, as the stages move on it."""

    fibre: Fibre
    limits: JointLimits
    coaxial_sets: tuple[CoaxialSet, ...]  # the model's (SmmModel.coaxial_sets)
    tolerance: Tolerance  # the query's: what an answer's configuration must reach
    collision: CollisionCheck  # the query's: the robot's bodies, the obstacles, the margin

    def kinematic(self) -> FibreSpace:
        """This space with collisions aside."""
        return replace(self, collision=CollisionCheck.none())

    def compiled(self) -> native.CompiledSpace | None:
        """This space as the compiled walks take it (a serial chain's fibre, checked for
        self-collision, a scene's obstacles, both or nothing), or None where they cannot:
        other kinematics, or a check that must see every verdict itself
        (`CollisionCheck.compiled_walks`); the walks' numpy loops take those."""
        fibre, collision, limits = self.fibre, self.collision, self.limits
        chain = fibre.chain
        if chain is None or not fibre.damping > 0 or not collision.compiled_walks:
            return None
        bodies, obstacles, moving = None, None, None
        robot = collision.robot
        if collision.active and robot is not None:
            bodies = robot.self_bodies(collision.margin_m)
            if collision.scene.obstacles:
                obstacles, moving = collision.scene.compiled, robot.moving_bodies.moving
        target = fibre.target
        return native.CompiledSpace(
            chain.fixed, chain.tip, fibre.task.position_axes, target.position_m,
            kernel_orientation(fibre.task, target), fibre.damping,
            limits.lower_rad, limits.upper_rad, limits.periodic,
            np.array([c.joint for c in self.coaxial_sets], dtype=np.int64),
            np.array([c.angle_rad for c in self.coaxial_sets]), bodies,
            collision.self_checked, obstacles, moving,
        )  # fmt: skip

    def accept(self, correction: Correction) -> Acceptance:
        """Which corrected configurations are valid: within the tolerance (NaN and inf
        errors fail it), inside the limits, and (checked for those only) free."""
        acceptance = accept(correction, self.tolerance, self.limits)
        on_fibre = np.flatnonzero(acceptance.on_fibre)
        if not self.collision.active or not len(on_fibre):
            return acceptance
        clearance = np.full(len(correction.q_rad), np.nan)  # (N,)
        free = acceptance.collision_free.copy()
        clearance[on_fibre], free[on_fibre] = self.collision.judged(correction.q_rad[on_fibre])
        return replace(acceptance, collision_free=free, clearance_m=clearance)

    def polish(
        self, q_rad: FloatArray, iterations: int = 4, max_move_rad: float = 0.01
    ) -> tuple[FloatArray, BoolArray]:  # (A, n) near the fibre -> (A, n), (A,)
        """Newton steps from configurations near the fibre (a walk's, within its projection
        tolerance) to the query's tolerance: the configurations (periodic joints wrapped)
        and which of them are valid, as `accept` judges a corrected sample, and moved at
        most `max_move_rad` (a tenth of the shortest walk step: the motions checked to
        the configuration still reach the polished one).

        Walks slide along limit faces, so many such configurations hold a joint on a
        limit, which a free Newton step pushes out: those joints are held, and a joint
        that a step still takes out is put back on its limit and held for a second
        pass."""
        limits = self.limits
        q = limits.wrap(q_rad)
        projected = project(self.fibre, q, iterations, locked=limits.on_limit(q))
        q, error = limits.wrap(projected.q_rad), projected.error  # (A, n), (A, m)
        out = ~limits.contains(q)
        if out.any():
            again = limits.clip(q[out])
            retried = project(self.fibre, again, iterations, locked=limits.on_limit(again))
            q[out], error[out] = limits.wrap(retried.q_rad), retried.error
        position_error_m, orientation_error_rad = error_norms(error, self.fibre.task)
        ok = self.tolerance.within(position_error_m, orientation_error_rad)
        ok &= np.all(np.isfinite(q), axis=1)
        ok &= limits.distance(q, limits.wrap(q_rad)) <= max_move_rad
        if ok.any():
            inside = np.flatnonzero(ok)
            ok[inside] = self.valid(q[inside])
        return q, ok

    def valid(self, q_rad: FloatArray) -> BoolArray:  # (A, n) on the fibre -> (A,)
        """Which configurations already on the fibre are inside the limits and free."""
        ok = self.limits.contains(q_rad)
        if self.collision.active and ok.any():
            inside = np.flatnonzero(ok)
            ok[inside] = self.collision.free(q_rad[inside])
        return ok

    def motion_valid(
        self,
        q_from_rad: FloatArray,  # (A, n) valid configurations
        q_to_rad: FloatArray,  # (A, n) the projections of a step from each
        error_norm: FloatArray,  # (A,) |e| at q_to_rad
        max_move_rad: float,  # a longer move is a jump
        tolerance: float,  # |e| a projected step must reach
        also: BoolArray | None = None,  # (A,) the walker's own conditions
        limit_check: LimitCheck | None = None,  # the step's interior too (None: its ends)
    ) -> BoolArray:  # (A,)
        """Which steps q_from -> q_to are valid motions on the fibre; the coaxial
        crossings, the limits between the step's ends (with `limit_check`) and then
        collisions are checked last, only for the steps that pass everything else."""
        moved = np.linalg.norm(q_to_rad - q_from_rad, axis=1)
        ok = (error_norm <= tolerance) & self.limits.contains(q_to_rad) & (moved <= max_move_rad)
        if also is not None:
            ok &= also
        if self.coaxial_sets and ok.any():
            crossed = np.flatnonzero(ok)
            ok[crossed] = self.crossings_on_fibre(q_from_rad[crossed], q_to_rad[crossed], tolerance)
        if limit_check is not None and ok.any():
            checked = np.flatnonzero(ok)
            ok[checked] = self.inside_between(
                q_from_rad[checked], q_to_rad[checked], limit_check, tolerance
            )
        if self.collision.active and ok.any():
            moving = np.flatnonzero(ok)
            ok[moving] = self.collision.free(q_to_rad[moving])
        return ok

    def inside_between(
        self,
        q_a_rad: FloatArray,  # (A, n) on the fibre, inside the limits
        q_b_rad: FloatArray,  # (A, n) on the fibre, inside the limits, a step from a
        check: LimitCheck,
        tolerance: float,  # |e| a point of the fine walk must reach
    ) -> BoolArray:  # (A,) False for a step whose interior the fine walk cannot follow
        """Steps whose interior stays inside the limits, as a walk at the check's finer
        spacing finds: a walk checks each step where it lands, so a step can pass over a
        stretch of the fibre outside the limits narrower than itself and join pieces that
        the limits cut apart (a 4-D fibre's thin pieces, where it touches a limit).

        A step needs no check where it is no longer than the spacing, or where no bounded
        joint is near enough a limit at both ends that a path `check.stretch` times the
        step long could reach it (its distances to the limit at both ends summing to
        more). Otherwise a walk goes from a toward b at steps of the spacing, re-aimed at b
        each step, and must get within one step of b in at most ceil(stretch x |b - a| /
        spacing) + 1 steps, each put on the fibre by Newton (at most
        LIMIT_CHECK_ITERATIONS steps, until within `tolerance`; a joint on one limit where
        the step starts and at b is held there, as a walk sliding along a limit face holds
        it), within `tolerance`, inside the limits, no farther than stretch x the spacing
        and nearer b. native.c's `inside_between` is the same, step by step.
        """
        ok = np.ones(len(q_a_rad), dtype=bool)
        limits, spacing = self.limits, check.spacing_rad
        lower, upper, bounded = limits.lower_rad, limits.upper_rad, ~limits.periodic
        length = np.linalg.norm(q_b_rad - q_a_rad, axis=1)  # (A,)
        reach = check.stretch * length
        near_low = (q_a_rad - lower) + (q_b_rad - lower) <= reach[:, None]
        near_high = (upper - q_a_rad) + (upper - q_b_rad) <= reach[:, None]
        near = (bounded & (near_low | near_high)).any(axis=1)
        rows = np.flatnonzero(near & (length > spacing))
        if not len(rows):
            return ok
        q, goal = q_a_rad[rows].copy(), q_b_rad[rows]  # (R, n)
        most = np.ceil(reach[rows] / spacing).astype(np.int64) + 1  # (R,) steps at most
        walking = np.ones(len(rows), dtype=bool)
        arrived = np.zeros(len(rows), dtype=bool)
        for step in range(int(most.max())):
            walking &= step < most
            left = np.linalg.norm(goal - q, axis=1)  # (R,)
            arrived |= walking & (left <= spacing)
            walking &= ~arrived
            index = np.flatnonzero(walking)
            if not len(index):
                break
            q_i, goal_i = q[index], goal[index]
            guess = q_i + spacing * (goal_i - q_i) / left[index, None]
            held = bounded & (
                ((q_i <= lower) & (goal_i <= lower)) | ((q_i >= upper) & (goal_i >= upper))
            )
            moved = project(self.fibre, guess, LIMIT_CHECK_ITERATIONS, locked=held, until=tolerance)
            q_new = moved.q_rad
            good = (moved.error_norm <= tolerance) & limits.contains(q_new)
            good &= np.linalg.norm(q_new - q_i, axis=1) <= check.stretch * spacing
            good &= np.linalg.norm(goal_i - q_new, axis=1) < left[index]
            walking[index[~good]] = False
            q[index[good]] = q_new[good]
        ok[rows] = arrived
        return ok

    def crossings_on_fibre(
        self,
        q_from_rad: FloatArray,  # (A, n) on the fibre
        q_to_rad: FloatArray,  # (A, n) on the fibre, one step further
        tolerance: float,  # |e| the crossing point must reach
        iterations: int = 4,  # Newton steps onto the fibre at the crossing
    ) -> BoolArray:  # (A,) False for a step that crosses a set where the fibre does not reach it
        """Steps that cross no coaxial set, or cross one where the fibre reaches it.

        A path on a fibre from one side of a set to the other (q_j - angle changing sign)
        passes through a point of the fibre on the set (connect/coaxial.py). For each set
        the step crosses (both ends within pi/2 of the angle), the point where the
        straight step meets the set is projected onto the fibre with joint j held at the
        set's angle: it must converge within `tolerance` without moving farther than the
        step is long.
        """
        ok = np.ones(len(q_from_rad), dtype=bool)
        for coaxial_set in self.coaxial_sets:
            j = coaxial_set.joint
            before = q_from_rad[:, j] - coaxial_set.angle_rad  # (A,)
            after = q_to_rad[:, j] - coaxial_set.angle_rad
            if self.limits.periodic[j]:
                before, after = wrap_to_pi(before), wrap_to_pi(after)
            crossing = np.flatnonzero(
                (before * after < 0) & (np.abs(before) < np.pi / 2) & (np.abs(after) < np.pi / 2)
            )
            if not len(crossing):
                continue
            fraction = before[crossing] / (before[crossing] - after[crossing])  # (C,)
            step = q_to_rad[crossing] - q_from_rad[crossing]  # (C, n)
            guess = q_from_rad[crossing] + fraction[:, None] * step
            guess[:, j] = coaxial_set.angle_rad
            locked = np.zeros_like(guess, dtype=bool)
            locked[:, j] = True
            on_set = project(self.fibre, guess, iterations, locked=locked)
            moved = np.linalg.norm(on_set.q_rad - guess, axis=1)
            reach = min(tolerance, SET_REACH_TOLERANCE)
            reached = (on_set.error_norm <= reach) & (moved <= np.linalg.norm(step, axis=1))
            ok[crossing] &= reached
        return ok
