"""Figure blocks of the scene section (docs/reports/scenes/<id>.json, `smm-train scenes`).

scenes-table                 one row per model with a scene report
scenes MODEL PATH [FORMAT]   one figure of docs/reports/scenes/MODEL.json (FORMAT as
                             tools/docs/topics/models.py's)
"""

from __future__ import annotations

from typing import Any

from tools.docs import sources
from tools.docs.blocks import block
from tools.docs.topics.models import (
    _table,
    bundled_models,
    format_value,
    machine_words,
    shared_cores,
    timed,
)


def scene_reports() -> dict[str, dict[str, Any]]:
    """Every scene report, by model id, in the models pages' order."""
    written = {
        n.removeprefix("scenes/") for n in sources.names(sources.REPORTS) if n.startswith("scenes/")
    }
    return {m: sources.report(f"scenes/{m}") for m in bundled_models() if m in written}


@block("scenes")
def scenes_figure(model_id: str, path: str, fmt: str = "3g") -> str:
    """One figure of a model's scene report."""
    data = sources.report(f"scenes/{model_id}")
    return format_value(sources.lookup(data, path, f"scenes/{model_id}.json"), fmt)


def _row(model_id: str, report: dict[str, Any]) -> list[str]:
    s = report["summary"]
    exact, rec, ms = s["exactness"], s["recall"], s["time"]["ms"]
    violations = exact["returned"]["violations"] + exact["recorded"]["violations"]
    checked = exact["returned"]["checked"] + exact["recorded"]["checked"]
    found = "-" if rec is None else (
        f"{format_value(rec['found_fraction'], 'pct')} "
        f"({format_value(rec['sphere_free_found_fraction'], 'pct')})"
    )  # fmt: skip
    return [
        f"`{model_id}`", str(report["targets"]), format_value(s["obstacles_mean"], "2g"),
        f"{checked:,}", str(violations), found, "-" if rec is None else str(rec["merges"]),
        format_value(s["free_space"]["lost_fraction"], "pct"),
        *(timed(report, ms[way]["median"]) for way in ("nothing_checked", "self_only", "scene")),
        timed(report, ms["10_boxes"]["median"]),
        f"{s['time']['ratio_boxes_to_self_only']:.2f}x",
    ]  # fmt: skip


@block("scenes-table")
def scenes_table() -> str:
    """The scene section's headline figures, one row per model with a scene report."""
    reports = scene_reports()
    header = ["model", "targets", "boxes (mean)", "configurations checked by coal",
              "violations", "free pieces found (of those the check frees)", "merges",
              "free space lost", "ms: nothing checked", "ms: self only", "ms: scene",
              "ms: 10 boxes", "10 boxes / self only"]  # fmt: skip
    rows = [_row(model_id, report) for model_id, report in reports.items()]
    legend = (
        "From each model's scene report (`docs/reports/scenes/<model>.md`). Violations: "
        "configurations the service returned or called free that coal finds in collision on "
        "the URDF's own geometry. Free pieces: those of the exact SMM (r = 1; for the "
        "iiwa14 position, r = 4, of the kinematic reference's grid cut by coal) of at least "
        "1 % of the fibre, found when a returned configuration lies on them; in brackets, "
        "of the pieces with a point the service's check calls free. Merges: returned "
        "components on two pieces of one exact component (across a collision cut). Free "
        "space lost: exact points free by coal that the service's check calls in "
        "collision. Times: per answer, median, in process, on "
        f"{machine_words(list(reports.values()))}"
        + ("; * other work shared the cores." if any(map(shared_cores, reports.values())) else ".")
    )
    return _table(header, rows) + "\n\n" + legend
