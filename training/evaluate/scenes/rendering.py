"""The scene section's report as Markdown (docs/reports/scenes/<model>.md), from its JSON."""

from __future__ import annotations

from typing import Any

from training.evaluate.scenes.summary import FOUND_GOAL, RATIO_GOAL
from training.evaluate.scenes.timing import TIMING_OBSTACLES, WAYS
from training.machine import Machine

WAY_NAMES = {
    "scene": "in its random scene",
    "self_only": "no obstacles, self-collision checked (as served)",
    "nothing_checked": "nothing checked (no obstacles, self off)",
    f"{TIMING_OBSTACLES}_boxes": f"exactly {TIMING_OBSTACLES} boxes",
}


def _g(value: float | None, digits: int = 3) -> str:
    return "n/a" if value is None else f"{value:.{digits}g}"


def _pct(value: float | None) -> str:
    return "n/a" if value is None else f"{100 * value:.2f} %"


def _exactness(report: dict[str, Any]) -> list[str]:
    ex = report["summary"]["exactness"]
    rows = [
        "| configurations | checked by coal | violations | least coal clearance (m) |",
        "|---|---|---|---|",
    ]
    for kind, name in (
        ("returned", "returned (members, path points)"),
        ("recorded", "called free on the way (sampled)"),
    ):
        rows.append(
            f"| {name} | {ex[kind]['checked']:,} | {ex[kind]['violations']} "
            f"| {_g(ex[kind]['worst_clearance_m'])} |"
        )
    rows += [
        "",
        f"The check called {ex['recorded_total']:,} distinct configurations free; at "
        f"most {report['settings']['recorded_checked_per_target']:,} per target, drawn at "
        "random, were checked by coal. Answers that differ from `run`'s (the recording "
        f"changed nothing when empty): {ex['answers_differing_from_run'] or 'none'}.",
    ]
    bad = ex["returned"]["targets_with_violations"] + ex["recorded"]["targets_with_violations"]
    if bad:
        rows.append(f"Targets with violations (replay their `request`): {sorted(set(bad))}.")
    return rows


def _missed(rec: dict[str, Any]) -> list[str]:
    """The missed pieces: where the check loses them, where the kinematic answer misses
    them too, and those the scene's answer alone lost."""
    missed = rec["missed"]
    if not missed:
        return []
    lost = sum(m["sphere_free_share"] == 0 for m in missed)
    kinematic = sum(m["sphere_free_share"] > 0 and m["missed_kinematically"] for m in missed)
    alone = rec["missed_in_the_scene"]
    listed = ", ".join(
        f"{m['index']} ({m['length_rad']:.2f} rad, {_pct(m['sphere_free_share'])} free by "
        "the check)"
        for m in alone
    )
    return [
        f"- Missed pieces: {len(missed)}; lying wholly where the check calls collision: "
        f"{lost}; missed by the answer with nothing checked too (kinematic misses): "
        f"{kinematic}; lost by the scene's answer alone: {len(alone)}"
        + (f": target {listed}." if alone else "."),
    ]


def _recall(report: dict[str, Any]) -> list[str]:
    rec = report["summary"]["recall"]
    if rec is None and report.get("task") == "axis":
        return [
            "Not measured for the tool-axis task: no exact reference here lists its fibre's "
            "free pieces (the pose's comes from the analytic IK, the iiwa14 position's from "
            "its grid); the answers' exactness against coal and the free space the check "
            "loses are measured; see [Models, Scenes](../../models.md#scenes)."
        ]
    if rec is None:
        return [
            "Not measured for this 4-D fibre: its robot's position reference has no graph to "
            "cut; see [Models, Scenes](../../models.md#scenes)."
        ]
    singular = rec["near_singular_targets"]
    settings = report["settings"]
    four_d = report.get("redundancy", 1) > 1
    unit = "component" if four_d else "curve"
    counted = (
        "on this coarser grid, which can split what the kinematic report's joins"
        if four_d
        else "as the kinematic report counts them"
    )
    finer = rec.get("finer_grid_targets", {})
    grid = (
        [
            f"- The reference: the kinematic reference's grid at {settings['position_grid_steps']} "
            f"steps times {settings['position_q7_layers']} values of q7, each node checked by "
            f"coal; a configuration lies on the piece of the nearest free node of its nearest "
            f"q7 value within {settings['position_match_rad']:g} rad. Where that grid finds a "
            f"merge, the target is measured again on finer grids "
            f"({', '.join(map(str, settings.get('position_finer_grid_steps', [])))} steps) "
            f"while one remains: {len(finer)} targets"
            + (
                ", " + ", ".join(f"{index} at {steps}" for index, steps in finer.items()) + "."
                if finer
                else "."
            )
        ]
        if four_d and "position_grid_steps" in settings
        else []
    )
    return [
        *grid,
        f"- Free pieces of at least {100 * report['settings']['min_piece_share']:g} % of the "
        f"fibre: {rec['pieces_asked']}, found {rec['pieces_found']} "
        f"(**{_pct(rec['found_fraction'])}**, goal {100 * FOUND_GOAL:g} %).",
        f"- Of those, pieces with a point the service's check calls free (the others lie "
        f"wholly in the free space the check loses): {rec['pieces_sphere_free']}, found "
        f"{rec['pieces_sphere_free_found']} (**{_pct(rec['sphere_free_found_fraction'])}**).",
        *_missed(rec),
        f"- Merges across a collision cut (a returned component on two pieces of one exact "
        f"{unit}): **{rec['merges']}** (goal 0)"
        + (f", targets {rec['targets_with_merges']}." if rec["merges"] else "."),
        f"- Returned components on two exact {unit}s (kinematic merges, {counted}): "
        f"{rec['merges_of_curves']}"
        + (f", targets {rec['targets_with_merges_of_curves']}" if rec["merges_of_curves"] else "")
        + f"; targets the answer flags near-singular: {singular or 'none'}.",
    ]


def _times(report: dict[str, Any]) -> list[str]:
    t = report["summary"]["time"]
    rows = ["| asked | median (ms) | p95 (ms) |", "|---|---|---|"]
    rows += [
        f"| {WAY_NAMES[way]} | {t['ms'][way]['median']:.1f} | {t['ms'][way]['p95']:.1f} |"
        for way in WAYS
    ]
    rows += [
        "",
        f"Median with {TIMING_OBSTACLES} boxes over median without a scene: "
        f"**{t['ratio_boxes_to_self_only']:.2f}x** (goal at most {RATIO_GOAL:g}x for "
        f"iiwa14-pose); over nothing checked: {t['ratio_boxes_to_nothing_checked']:.2f}x.",
    ]
    return rows


def markdown(model_id: str, report: dict[str, Any]) -> str:
    """The report's page."""
    s, m = report["summary"], report["machine"]
    free = s["free_space"]
    lines = [
        f"# Scenes: {model_id}",
        "",
        f"`{report['model']}`, {report['targets']} targets (seed {report['seed']}), 1 to "
        f"{report['max_obstacles']} random boxes each (mean {s['obstacles_mean']:.1f}), margin "
        f"{report['margin_m']:g} m, {report['num_samples']} samples. Written by `smm-train "
        f"scenes --model {model_id} --targets {report['targets']}"
        + (f" --margin-m {report['margin_m']:g}" if report["margin_m"] > 0 else "")
        + "`; each target's `request` in "
        "the JSON replays it as a POST /smm body. What is measured: "
        "[Models, Scenes](../../models.md#scenes).",
        "",
        "## Exact against coal on the URDF's geometry",
        "",
        *_exactness(report),
        "",
        "## Free pieces of the exact SMM found",
        "",
        *_recall(report),
        "",
        "## Free space lost",
        "",
        f"Of {free['coal_free_points']:,} exact points free by coal, the service's check calls "
        f"{free['lost_points']:,} in collision: **{_pct(free['lost_fraction'])}**.",
        "",
        "## Time",
        "",
        *_times(report),
        "",
        f"Times measured in process, warm, on: {Machine.from_json(m).describe()}.",
        "",
    ]
    return "\n".join(lines)
