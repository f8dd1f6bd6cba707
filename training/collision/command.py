"""`smm-train collision`: (re)build collision.json in an existing model directory.

    smm-train collision --model panda-pose [--srdf PATH] [--spheres-per-body K]
                        [--configurations N] [--models-dir DIR]

The model's flow was trained on its chain, so the robot's URDF as it is now must give
exactly the model's chain.json (read by `training.kinematics`); the command refuses
otherwise, naming the first difference. It then builds the collision model
(`training.collision`: spheres per body, disabled pairs, free space lost) from the URDF's
<collision> geometry, writes collision.json, lists it in the manifest's files with its
sha256, records the URDF's current sha256 in the manifest (its kinematics verified
identical; only its geometry may have changed) and the build in manifest.collision, with
this command. The SRDF is --srdf, else the robot file's `srdf`, else none (the pairs are
then sampled). The change is made on a hidden copy of the model, loaded as the service
loads it, and swapped in whole.
"""

from __future__ import annotations

import argparse
import json
import shlex
from pathlib import Path

from service.manifest import (
    CHAIN_FILE,
    COLLISION_FILE,
    MANIFEST_FILE,
    ChainSpec,
    FileRef,
    Manifest,
)
from service.models.registry import load_model, sha256_of
from training.checkout import git_commit
from training.collision.pairs import DEFAULT_CONFIGURATIONS
from training.collision.record import CollisionSettings, write_collision
from training.collision.spheres import DEFAULT_SPHERES_PER_BODY
from training.kinematics import chain_spec, load_chain
from training.robots import robot_spec
from training.staging import staged_copy
from training.train_command import default_models_dir


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--model", required=True, help="model id: a directory of --models-dir")
    parser.add_argument(
        "--srdf", type=Path, default=None,
        help="the robot's SRDF: its disable_collisions are the pairs not checked, beside the "
        "adjacent ones (default: the robot file's srdf; without one, the pairs are sampled)",
    )  # fmt: skip
    parser.add_argument(
        "--spheres-per-body", type=int, default=DEFAULT_SPHERES_PER_BODY,
        help="at most this many spheres cover each body (default: %(default)s)",
    )  # fmt: skip
    parser.add_argument(
        "--configurations", type=int, default=DEFAULT_CONFIGURATIONS,
        help="random configurations the default/always/never pairs and the free space lost "
        "are measured on (default: %(default)s, MoveIt's)",
    )  # fmt: skip
    parser.add_argument("--seed", type=int, default=0, help="of the configurations and k-means")
    parser.add_argument(
        "--package-dir", type=Path, default=None,
        help="resolves package://PACKAGE/PATH mesh filenames as DIR/PACKAGE/PATH",
    )  # fmt: skip
    parser.add_argument(
        "--models-dir", type=Path, default=default_models_dir(),
        help="the models directory (default: %(default)s)",
    )  # fmt: skip


def chain_difference(expected: ChainSpec, actual: ChainSpec) -> str | None:
    """The first field where `actual` differs from `expected`, in words; None if equal."""
    if expected == actual:
        return None
    for field in ("base_link", "end_effector_link", "tip"):
        if getattr(expected, field) != getattr(actual, field):
            return f"{field}: {getattr(expected, field)} -> {getattr(actual, field)}"
    if expected.joint_names != actual.joint_names:
        return f"joints: {expected.joint_names} -> {actual.joint_names}"
    for old, new in zip(expected.joints, actual.joints, strict=True):
        for field in ("origin", "axis"):
            if getattr(old, field) != getattr(new, field):
                return f"joint {old.name!r} {field}: {getattr(old, field)} -> {getattr(new, field)}"
    return "the chain differs"


def rebuild_collision(
    model_dir: Path, models_dir: Path, settings: CollisionSettings, command: str
) -> Manifest:
    """collision.json of an existing model rebuilt (module docstring); the new manifest."""
    manifest = Manifest.model_validate_json((model_dir / MANIFEST_FILE).read_bytes())
    if CHAIN_FILE not in manifest.files:
        raise ValueError(
            f"{model_dir}: the model has no chain.json; run smm-train train --robot "
            f"{manifest.robot} --task {manifest.task.name} --refresh-kinematics first"
        )
    chain = ChainSpec.model_validate_json((model_dir / CHAIN_FILE).read_bytes())
    urdf_path = models_dir / manifest.urdf.path
    now = chain_spec(load_chain(urdf_path, chain.end_effector_link, chain.base_link))
    difference = chain_difference(chain, now)
    if difference is not None:
        raise ValueError(
            f"{urdf_path} no longer gives {model_dir / CHAIN_FILE} ({difference}): the flow "
            "was trained on that chain; retrain the model instead"
        )
    with staged_copy(model_dir) as staging:
        record = write_collision(
            staging, models_dir, urdf_path, chain, manifest.joints, settings, command,
            git_commit(),
        )  # fmt: skip
        files = {name: digest for name, digest in manifest.files.items() if name != COLLISION_FILE}
        if record is not None:
            files[COLLISION_FILE] = sha256_of(staging / COLLISION_FILE)
        manifest = manifest.model_copy(
            update={
                "files": files,
                "urdf": FileRef(path=manifest.urdf.path, sha256=sha256_of(urdf_path)),
                "collision": record,
            }
        )
        (staging / MANIFEST_FILE).write_text(
            manifest.model_dump_json(indent=2, exclude_unset=True) + "\n"
        )
        load_model(staging, threads=1)  # verifies every file's sha256, the URDF's too
    return manifest


def run_command(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    models_dir: Path = args.models_dir
    model_dir = models_dir / args.model
    if not (model_dir / MANIFEST_FILE).is_file():
        present = sorted(p.parent.name for p in models_dir.glob(f"*/{MANIFEST_FILE}"))
        raise SystemExit(f"smm-train: error: --model {args.model!r}: choose from {present}")
    try:
        manifest = Manifest.model_validate_json((model_dir / MANIFEST_FILE).read_bytes())
        robot = robot_spec(manifest.robot, models_dir)
        srdf = args.srdf
        if srdf is None and robot.srdf is not None:
            srdf = models_dir / robot.srdf
        settings = CollisionSettings(
            srdf, args.spheres_per_body, args.configurations, args.seed, args.package_dir
        )
        manifest = rebuild_collision(
            model_dir, models_dir, settings, shlex.join(["smm-train", *args.argv])
        )
    except ValueError as error:
        raise SystemExit(f"smm-train: error: {error}") from None
    record = None if manifest.collision is None else manifest.collision.model_dump()
    print(json.dumps({"model": args.model, "collision": record}, indent=1))
