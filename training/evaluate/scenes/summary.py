"""The scene section's figures over every target: violations, pieces found and merges,
free space lost, and the four timings with the timing goal's ratio."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from training.evaluate.scenes.timing import TIMING_OBSTACLES, WAYS, median_p95

FOUND_GOAL = 0.99  # of the free pieces of at least 1 % of the fibre
RATIO_GOAL = 1.5  # median time with TIMING_OBSTACLES boxes over that without a scene (iiwa14 pose)


def _worst(values: Sequence[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return min(present) if present else None


def exactness_summary(targets: Sequence[dict[str, Any]]) -> dict[str, object]:
    """Violations over the returned and the recorded configurations, and the least coal
    clearance of any."""
    out: dict[str, object] = {}
    for kind in ("returned", "recorded"):
        out[kind] = {
            "checked": sum(t[kind]["checked"] for t in targets),
            "violations": sum(t[kind]["violations"] for t in targets),
            "targets_with_violations": [t["index"] for t in targets if t[kind]["violations"]],
            "worst_clearance_m": _worst([t[kind]["worst_clearance_m"] for t in targets]),
        }
    out["recorded_total"] = sum(t["recorded_total"] for t in targets)
    out["answers_differing_from_run"] = [t["index"] for t in targets if not t["same_as_run"]]
    return out


def recall_summary(targets: Sequence[dict[str, Any]]) -> dict[str, object] | None:
    """Free pieces found and merges across a collision cut (pose targets only)."""
    with_recall = [t for t in targets if "recall" in t]
    if not with_recall:
        return None

    def total(key: str) -> int:
        return sum(t["recall"][key] for t in with_recall)

    asked, found = total("asked"), total("found")
    first_grid = min(t["recall"].get("grid_steps", 0) for t in with_recall)
    sphere_free, sphere_free_found = total("sphere_free"), total("sphere_free_found")
    missed = [
        {"index": t["index"], "length_rad": length, "sphere_free_share": share,
         "missed_kinematically": kinematic}
        for t in with_recall
        for length, share, kinematic in zip(
            t["recall"]["missed_length_rad"], t["recall"]["missed_sphere_free_share"],
            t["recall"]["missed_kinematically"], strict=True,
        )
    ]  # fmt: skip
    lost_to_scene = [
        m for m in missed if m["sphere_free_share"] > 0 and not m["missed_kinematically"]
    ]
    return {
        "pieces_asked": asked,
        "pieces_found": found,
        "found_fraction": found / asked if asked else None,
        "pieces_sphere_free": sphere_free,
        "pieces_sphere_free_found": sphere_free_found,
        "sphere_free_found_fraction": sphere_free_found / sphere_free if sphere_free else None,
        "merges": total("merges"),
        "targets_with_merges": [t["index"] for t in with_recall if t["recall"]["merges"]],
        "merges_of_curves": total("merges_of_curves"),
        "targets_with_merges_of_curves": [
            t["index"] for t in with_recall if t["recall"]["merges_of_curves"]
        ],
        "near_singular_targets": [t["index"] for t in with_recall if t["near_singular"]],
        # 4-D: the targets measured on a finer grid than the first, and its steps
        "finer_grid_targets": {
            str(t["index"]): t["recall"]["grid_steps"]
            for t in with_recall
            if t["recall"].get("grid_steps", 0) > first_grid
        },
        # missed pieces the check frees somewhere and the kinematic answer found
        "missed_in_the_scene": lost_to_scene,
        "missed": missed,
    }


def time_summary(targets: Sequence[dict[str, Any]]) -> dict[str, object]:
    """Median and p95 of each way's time, and the ratio of the medians with
    TIMING_OBSTACLES boxes to without a scene (self-collision on, as served)."""
    ways = {way: median_p95([t["time_ms"][way] for t in targets]) for way in WAYS}
    boxes = ways[f"{TIMING_OBSTACLES}_boxes"]["median"]
    return {
        "ms": ways,
        "ratio_boxes_to_self_only": boxes / ways["self_only"]["median"],
        "ratio_boxes_to_nothing_checked": boxes / ways["nothing_checked"]["median"],
        "ratio_scene_to_self_only": ways["scene"]["median"] / ways["self_only"]["median"],
    }


def summary(targets: Sequence[dict[str, Any]]) -> dict[str, object]:
    """Every figure of the section (module docstring)."""
    coal_free = sum(t["free_space"]["coal_free"] for t in targets)
    lost = sum(t["free_space"]["lost"] for t in targets)
    obstacles = [len(t["request"]["obstacles"]) for t in targets]
    return {
        "exactness": exactness_summary(targets),
        "recall": recall_summary(targets),
        "free_space": {
            "coal_free_points": coal_free,
            "lost_points": lost,
            "lost_fraction": lost / coal_free if coal_free else None,
        },
        "time": time_summary(targets),
        "obstacles_mean": sum(obstacles) / len(obstacles),
        "timing_obstacles_min": min(t["timing_obstacles"] for t in targets),
        "components_mean": sum(t["components"] for t in targets) / len(targets),
        "targets_without_components": [t["index"] for t in targets if not t["components"]],
    }
