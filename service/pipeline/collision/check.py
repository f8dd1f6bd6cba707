"""One request's collision question: is a configuration free of the robot's own bodies and
of the scene's obstacles, by at least the margin, and how far is it from both.

Clearance is the least signed distance from the robot's spheres to another body's (the
pairs not disabled) and from its moving bodies' spheres to the obstacles: a lower bound
of the distance between the URDF's own geometry, since the spheres cover it. A
configuration is free when its clearance is at least the margin.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from service.pipeline.arrays import BoolArray, FloatArray
from service.pipeline.collision.robot import RobotSpheres
from service.pipeline.collision.scene import Scene

# Configurations placed per pass: the spheres' temporaries stay a few MB.
CHUNK = 1024


@dataclass(frozen=True)
class CollisionCheck:
    """What a query checks: the model's bodies (None: its URDF has no collision geometry),
    whether against each other, the request's obstacles, and the margin."""

    robot: RobotSpheres | None
    scene: Scene
    check_self: bool
    margin_m: float
    threads: int = 1  # the compiled self-clearance's rows split over this many (rows.py)
    # Whether the compiled walks may decide this check's verdicts inside their own loops
    # (native.c, space.py's `compiled`); a check that must see every verdict itself (the
    # evaluation's recorder, which has coal check each configuration called free) says
    # False, and the walks then ask it step by step.
    compiled_walks: ClassVar[bool] = True

    @classmethod
    def none(cls) -> CollisionCheck:
        """Nothing checked: the fibre inside the limits, collisions aside."""
        return cls(robot=None, scene=Scene(), check_self=False, margin_m=0.0)

    @property
    def self_checked(self) -> bool:
        """Self-collision is checked: asked for, and the model has bodies to check."""
        return self.check_self and self.robot is not None and len(self.robot.pair_a) > 0

    @property
    def active(self) -> bool:
        """Anything to check at all: self-collision, or obstacles and bodies that move."""
        if self.robot is None:
            return False
        return self.self_checked or (bool(self.scene.obstacles) and bool(self.robot.moving.any()))

    def clearance_m(self, q_rad: FloatArray) -> FloatArray:  # (B, n) -> (B,)
        """The least distance to the robot itself and to the obstacles; +inf when nothing
        is checked."""
        clearance = np.full(len(q_rad), np.inf)
        if not self.active or self.robot is None:
            return clearance
        robot = self.robot
        for start in range(0, len(q_rad), CHUNK):
            span = slice(start, start + CHUNK)
            q = q_rad[span]  # (C, n)
            # The bodies are placed (every frame stored) only for the obstacles; the
            # self-clearance and its refined pass place their own, row by row.
            placed = robot.place(q) if self.scene.obstacles else None
            if self.self_checked:
                clearance[span] = self._self_clearance_m(robot, q)
            if placed is not None:
                clearance[span] = self.scene.clearance_m(placed, robot, clearance[span])
            near = np.flatnonzero(clearance[span] < self.margin_m)  # the hulls decide
            if not len(near):
                continue
            refined = np.full(len(near), np.inf)
            if self.self_checked:  # itself: compiled, at joint values
                refined = robot.refined_self_clearance_at_m(q[near], self.margin_m)
            if placed is not None:
                alive = refined >= self.margin_m  # not free on itself: no obstacle asked
                refined[alive] = np.minimum(
                    refined[alive],
                    self.scene.refined_clearance_m(placed, robot, near[alive], self.margin_m),
                )
            # Free by the hulls: their bound; not free: the spheres' (a lower bound of the
            # least distance over everything, where the refined passes stop early).
            free = refined >= self.margin_m
            clearance[span][near[free]] = refined[free]
        return clearance

    def _self_clearance_m(self, robot: RobotSpheres, q_rad: FloatArray) -> FloatArray:
        """The robot's self-clearance at joint values (B,), the first part of the rows on the
        row helper with more than one thread (rows.helper_rows)."""
        return robot.self_clearance_at_m(q_rad, self.threads)

    def clearances_m(self, parts: list[FloatArray]) -> list[FloatArray]:
        """`clearance_m` of several arrays (k_i, n) in one call (each call costs a few
        hundred microseconds however few its rows), split back: (k_i,) each."""
        if not parts:
            return []
        measured = self.clearance_m(np.concatenate(parts))
        return np.split(measured, np.cumsum([len(p) for p in parts[:-1]]))

    def judged(self, q_rad: FloatArray) -> tuple[FloatArray, BoolArray]:  # (B, n) -> (B,) x 2
        """Each configuration's clearance (inf where nothing is checked) and whether it is
        clear by at least the margin (NaN rows are not): the verdict of `free` with the
        figure it rests on, for a stage that keeps the figure."""
        if not self.active:
            return np.full(len(q_rad), np.inf), np.ones(len(q_rad), dtype=bool)
        clearance = self.clearance_m(q_rad)
        return clearance, clearance >= self.margin_m

    def free(self, q_rad: FloatArray) -> BoolArray:  # (B, n) -> (B,)
        """Which configurations are clear by at least the margin (NaN rows are not)."""
        return self.judged(q_rad)[1]
