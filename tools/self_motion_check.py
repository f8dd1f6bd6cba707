"""Self-motion paths on the iiwa14 position (r = 4) or axis (r = 2) task, against known
self-motions, and their cost.

    python -m tools.self_motion_check --pairs 100 --out docs/benchmark/self-motion.json
    python -m tools.self_motion_check --model iiwa14-axis --pairs 100 \
        --out docs/benchmark/self-motion-iiwa14-axis.json

Pairs: from a configuration uniform in 0.8 x the limits (seed 20261127), a random walk
on its target's fibre (`training.evaluate.walks.null_space_walk`: 0.05 rad steps along the
null space, inside the limits, each projected to 1e-10), drawn again until its ends are
at least `--min-chord` rad apart; start and goal are its ends, so a self-motion joins
them. Each pair is asked in process (`self_motion`, the model's default num_samples,
self-collision as POST /smm checks it by default, seed = the pair's index) for the goal
configuration and for max_limit_margin, and each path is checked by the DH table
(training/evaluate/references/iiwa14.py, no service code): every point within 1e-6 m of
the target (and, on the axis task, its flange z axis within 1e-6 rad of the target's) and
inside the limits, consecutive points at most 0.05 rad apart, the ends
within 1e-6 rad of start and goal; max_limit_margin's end at least the best margin of the
start component's roadmap nodes. The cost: the median wall time of the configuration
request against a plain `run` of the same query, interleaved pair by pair on this
machine (compare only within one run).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from service.manifest import REPO_MODELS_DIR
from service.models.registry import load_model
from service.pipeline.run import run
from service.pipeline.self_motion import Goal, SelfMotion, self_motion
from service.pipeline.types import Query
from training.evaluate.references.iiwa14 import LIMITS_RAD, dh_pose
from training.evaluate.walks import null_space_walk
from training.machine import Machine

SEED = 20261127
SPACING_RAD = 0.05


def margin_rad(q_rad: np.ndarray) -> np.ndarray:
    """The reference's symmetric limits: the least distance of any joint to its limit."""
    return np.min(LIMITS_RAD - np.abs(q_rad), axis=-1)


MODELS = ("iiwa14-position", "iiwa14-axis")


def path_check(
    motion: SelfMotion, goal: np.ndarray, ends: np.ndarray | None, axis: bool
) -> dict[str, Any]:
    """The independent figures of one answer's path (None where it has none): goal is the
    target's DH pose (4, 4); with `axis`, its z axis is checked too."""
    if motion.path_rad is None:
        return {"ok": False, "status": motion.status}
    path = motion.path_rad
    reached = dh_pose(path)
    error_m = float(np.linalg.norm(reached[:, :3, 3] - goal[:3, 3], axis=1).max())
    angle_rad = 0.0
    if axis:
        tool = reached[:, :3, 2]
        sine = np.linalg.norm(np.cross(tool, goal[:3, 2]), axis=1)
        angle_rad = float(np.arctan2(sine, tool @ goal[:3, 2]).max())
    spacing = float(np.linalg.norm(np.diff(path, axis=0), axis=1).max()) if len(path) > 1 else 0.0
    inside = bool(np.all(np.abs(path) <= LIMITS_RAD))
    end_gap = 0.0 if ends is None else float(np.abs(path[[0, -1]] - ends).max())
    return {
        "ok": error_m <= 1e-6
        and angle_rad <= 1e-6
        and spacing <= SPACING_RAD
        and inside
        and end_gap <= 1e-6,
        "status": motion.status,
        "max_position_error_m": error_m,
        "max_axis_angle_rad": angle_rad,
        "max_spacing_rad": spacing,
        "inside_limits": inside,
        "max_end_gap_rad": end_gap,
        "points": len(path),
        "length_rad": motion.length_rad,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", choices=MODELS, default=MODELS[0])
    parser.add_argument("--pairs", type=int, default=100)
    parser.add_argument("--min-chord", type=float, default=1.5, help="rad between the ends")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    machine = Machine.now()
    model = load_model(REPO_MODELS_DIR / args.model, threads=0)
    axis = model.manifest.task.tool_axis is not None
    rng = np.random.default_rng(SEED)
    rows: list[dict[str, Any]] = []
    motion_ms: list[float] = []
    plain_ms: list[float] = []
    for index in range(args.pairs):
        walk = np.zeros((1, 7))
        while np.linalg.norm(walk[-1] - walk[0]) < args.min_chord:
            q0 = rng.uniform(-0.8 * LIMITS_RAD, 0.8 * LIMITS_RAD)
            walk = null_space_walk(model, q0, steps=160, seed=index)
        goal = dh_pose(q0[None])[0]
        x, y, z = (float(v) for v in goal[:3, 2])
        direction = (x, y, z) if axis else None
        query = Query.for_model(
            model.manifest, position_m=goal[:3, 3].tolist(), axis=direction, seed=index
        )
        started = time.perf_counter()
        motion = self_motion(model, query, walk[0], Goal(configuration_rad=walk[-1]))
        motion_ms.append((time.perf_counter() - started) * 1e3)
        started = time.perf_counter()
        run(model, query)
        plain_ms.append((time.perf_counter() - started) * 1e3)
        row: dict[str, Any] = {"chord_rad": float(np.linalg.norm(walk[-1] - walk[0]))}
        row["configuration"] = path_check(motion, goal, np.stack([walk[0], walk[-1]]), axis)
        best = self_motion(model, query, walk[0], Goal(objective="max_limit_margin"))
        margin = path_check(best, goal, None, axis)
        if best.path_rad is not None:
            roadmap = best.result.components[best.start_component].roadmap
            assert roadmap is not None
            margin["end_margin_rad"] = float(margin_rad(best.path_rad[-1]))
            margin["best_node_margin_rad"] = float(margin_rad(roadmap.q_rad).max())
            margin["ok"] = margin["ok"] and (
                margin["end_margin_rad"] >= margin["best_node_margin_rad"] - 1e-12
            )
        row["max_limit_margin"] = margin
        rows.append(row)
        print(index, json.dumps(row["configuration"]), flush=True)
    ok = [r["configuration"]["ok"] for r in rows]
    result = {
        "model": args.model,
        "pairs": args.pairs,
        "min_chord_rad": args.min_chord,
        "ok_pairs": int(np.sum(ok)),
        "ok_fraction": float(np.mean(ok)),
        "max_limit_margin_ok_pairs": int(np.sum([r["max_limit_margin"]["ok"] for r in rows])),
        "max_position_error_m": max(
            r["configuration"].get("max_position_error_m", 0.0) for r in rows
        ),
        "max_axis_angle_rad": max(r["configuration"].get("max_axis_angle_rad", 0.0) for r in rows),
        "max_spacing_rad": max(r["configuration"].get("max_spacing_rad", 0.0) for r in rows),
        "median_chord_rad": float(np.median([r["chord_rad"] for r in rows])),
        "median_length_rad": float(
            np.median([r["configuration"].get("length_rad") or np.nan for r in rows])
        ),
        "self_motion_median_ms": float(np.median(motion_ms)),
        "plain_median_ms": float(np.median(plain_ms)),
        "cost_ratio": float(np.median(motion_ms) / np.median(plain_ms)),
        "rows": rows,
        "command": f"python -m tools.self_motion_check --model {args.model} --pairs "
        f"{args.pairs} --min-chord {args.min_chord}",
        "machine": machine.ended().as_json(),
    }
    text = json.dumps(result, indent=1)
    if args.out is not None:
        args.out.write_text(text + "\n")
    summary = {k: v for k, v in result.items() if k not in ("rows", "machine")}
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
