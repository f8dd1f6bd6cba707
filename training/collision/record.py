"""A model directory's collision.json and the manifest's record of it, written together.

`write_collision` builds the collision model of the model's URDF (and SRDF) for its
chain, writes collision.json into the (staging) model directory and returns the
CollisionRecord the manifest keeps, or None (and no file) when the URDF has no collision
geometry on the chain. Both `smm-train train` at export and `smm-train collision` (a
rebuild in an existing model) write through it, so the two agree.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from service.manifest import (
    COLLISION_FILE,
    ChainSpec,
    CollisionRecord,
    CollisionSpec,
    FileRef,
    JointSpec,
)
from service.models.registry import sha256_of
from training.collision.build import build_collision_model
from training.collision.pairs import DEFAULT_CONFIGURATIONS
from training.collision.spheres import DEFAULT_SPHERES_PER_BODY


@dataclass(frozen=True)
class CollisionSettings:
    """What the build takes beyond the URDF and the chain."""

    srdf_path: Path | None = None
    spheres_per_body: int = DEFAULT_SPHERES_PER_BODY
    configurations: int = DEFAULT_CONFIGURATIONS
    seed: int = 0
    package_dir: Path | None = None


def models_relative(path: Path, models_dir: Path) -> str:
    """`path` relative to the models directory (FileRef.path), or absolute when outside it."""
    resolved, root = path.resolve(), models_dir.resolve()
    if resolved.is_relative_to(root):
        return os.path.relpath(resolved, root)
    return str(resolved)


def write_collision(
    model_dir: Path, models_dir: Path, urdf_path: Path, chain: ChainSpec, joints: JointSpec,
    settings: CollisionSettings, command: str, git_commit: str,
) -> CollisionRecord | None:  # fmt: skip
    """Build and write `model_dir`/collision.json (module docstring); None, and any old
    collision.json removed, when there is no collision geometry."""
    built = build_collision_model(
        urdf_path, chain, joints, settings.srdf_path, settings.spheres_per_body,
        settings.configurations, settings.seed, settings.package_dir,
    )  # fmt: skip
    target = model_dir / COLLISION_FILE
    if built is None:
        target.unlink(missing_ok=True)
        return None
    target.write_text(compact_json(built.spec))
    srdf = settings.srdf_path
    return CollisionRecord(
        command=command,
        urdf_sha256=sha256_of(urdf_path),
        srdf=None
        if srdf is None
        else FileRef(path=models_relative(srdf, models_dir), sha256=sha256_of(srdf)),
        sphere_count=built.sphere_count,
        configurations_sampled=built.configurations_sampled,
        free_space_lost_fraction=round(built.free_space_lost_fraction, 6),
        wall_time_s=round(built.wall_time_s, 1),
        git_commit=git_commit,
    )


def compact_json(spec: CollisionSpec) -> str:
    """collision.json with a line per body and per disabled pair: its hulls hold tens of
    thousands of numbers, a line each when indented."""
    data = spec.model_dump(mode="json")
    lines = ["{", f'"format_version": {data["format_version"]},', '"bodies": [']
    lines += [json.dumps(body) + "," for body in data["bodies"]]
    lines[-1] = lines[-1].rstrip(",")
    lines += ["],", '"disabled_pairs": [']
    lines += [json.dumps(pair) + "," for pair in data["disabled_pairs"]]
    lines[-1] = lines[-1].rstrip(",")
    lines += ["]", "}"]
    return "\n".join(lines) + "\n"
