"""The body pairs never checked, the way MoveIt's setup assistant decides them.

- adjacent: two bodies joined by a joint of the URDF tree, fixed joints included; a link
  without geometry is walked through (the Panda's panda_link8 joins panda_link7 and
  panda_hand), so its neighbours with geometry are adjacent to each other.
- default: in collision at the default configuration, each joint at 0 or, where 0 is
  outside its limits, at mid-range (MoveIt's default joint values): a pair that touches
  at the robot's home is taken to be meant to (the Panda's SRDF disables panda_link5 and
  panda_link7 so, their covers overlapping at rest).
- always: in collision in at least ALWAYS_FRACTION of the sampled configurations
  (MoveIt's setup assistant disables at 95 %: a pair that always touches says nothing
  about a configuration; two bodies fixed to each other and overlapping, typically).
- never: in collision in none of the sampled configurations (MoveIt samples 10,000 by
  default, as `DEFAULT_CONFIGURATIONS` does here): the pair is taken to be out of reach.

The configurations are uniform in the joint limits, the collisions coal's on the URDF's
own geometry (`training.evaluate.references.collision`). With the robot's SRDF, its
`disable_collisions` are taken instead of sampling (reason "srdf"), beside the adjacent
pairs found here (a pair that is both keeps "adjacent").
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from service.manifest import DisabledPair, DisabledReason, JointSpec
from service.pipeline.arrays import FloatArray
from training.collision.geometry import Body

ALWAYS_FRACTION = 0.95
DEFAULT_CONFIGURATIONS = 10_000


def _key(a: str, b: str) -> tuple[str, str]:
    first, second = sorted((a, b))
    return first, second


def adjacent_pairs(urdf_path: Path, bodies: Sequence[Body]) -> list[tuple[str, str]]:
    """Pairs of bodies joined by a joint, walking through links without geometry."""
    robot = ET.fromstring(urdf_path.read_text())
    neighbours: dict[str, set[str]] = {}
    for joint in robot.findall("joint"):
        parent, child = joint.find("parent"), joint.find("child")
        if parent is None or child is None:
            raise ValueError(f"{urdf_path}: joint {joint.get('name')!r} lacks parent or child")
        a, b = parent.get("link", ""), child.get("link", "")
        neighbours.setdefault(a, set()).add(b)
        neighbours.setdefault(b, set()).add(a)
    names = {body.link for body in bodies}
    pairs = set()
    for body in bodies:
        seen, pending = {body.link}, list(neighbours.get(body.link, ()))
        while pending:
            link = pending.pop()
            if link in seen:
                continue
            seen.add(link)
            if link in names:
                pairs.add(_key(body.link, link))
            elif not _has_geometry(robot, link):
                pending += neighbours.get(link, ())
    return sorted(pairs)


def _has_geometry(robot: ET.Element, link: str) -> bool:
    return any(
        element.get("name") == link and element.find("collision") is not None
        for element in robot.findall("link")
    )


def srdf_pairs(srdf_path: Path, bodies: Sequence[Body]) -> list[tuple[str, str]]:
    """The SRDF's disable_collisions between two of the bodies (pairs naming a link that
    is not a body, one without geometry or off the chain, are not the model's)."""
    try:
        robot = ET.fromstring(srdf_path.read_text())
    except ET.ParseError as error:
        raise ValueError(f"{srdf_path}: not an SRDF: {error}") from None
    if robot.tag != "robot":
        raise ValueError(f"{srdf_path}: not an SRDF: the root element is <{robot.tag}>")
    names = {body.link for body in bodies}
    pairs = set()
    for element in robot.findall("disable_collisions"):
        a, b = element.get("link1", ""), element.get("link2", "")
        if a in names and b in names and a != b:
            pairs.add(_key(a, b))
    return sorted(pairs)


def default_configuration(joints: JointSpec) -> FloatArray:  # (1, n)
    """MoveIt's default joint values: 0, or mid-range where 0 is outside the limits."""
    lower, upper = np.asarray(joints.lower_rad), np.asarray(joints.upper_rad)
    inside = (lower <= 0.0) & (upper >= 0.0)
    return np.where(inside, 0.0, (lower + upper) / 2)[None]


def sampled_pairs(
    names: Sequence[str], pairs: Sequence[tuple[int, int]], touching: np.ndarray,
    at_default: np.ndarray,
) -> list[DisabledPair]:  # fmt: skip
    """The 'default', 'always' and 'never' pairs among `pairs` (index pairs into `names`)
    from `touching` (B, P), whether pair p collided at each sampled configuration, and
    `at_default` (P,), at the default configuration."""
    fraction = touching.mean(axis=0) if len(touching) else np.zeros(len(pairs))
    disabled = []
    for (a, b), share, default in zip(pairs, fraction, at_default, strict=True):
        reason: DisabledReason | None = None
        if default:
            reason = "default"
        elif share >= ALWAYS_FRACTION:
            reason = "always"
        elif share == 0.0:
            reason = "never"
        if reason is not None:
            disabled.append(DisabledPair(links=_key(names[a], names[b]), reason=reason))
    return disabled


def tagged(pairs: Sequence[tuple[str, str]], reason: DisabledReason) -> list[DisabledPair]:
    return [DisabledPair(links=pair, reason=reason) for pair in pairs]
