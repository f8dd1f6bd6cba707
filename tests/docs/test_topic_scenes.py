"""The scene section's figure blocks (tools/docs/topics/scenes.py) write what the committed
scene reports hold: one row per model with a docs/reports/scenes/<model>.json, each cell
checked against the JSON read directly, and a single figure read by its path."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from tools.docs.blocks import run_block

ROOT = Path(__file__).resolve().parents[2]
SCENES = ROOT / "docs" / "reports" / "scenes"


def reports() -> dict[str, dict[str, Any]]:
    return {p.stem: json.loads(p.read_text()) for p in sorted(SCENES.glob("*.json"))}


def test_scenes_table_has_each_reports_figures() -> None:
    table = run_block("scenes-table", [])
    cells = {
        line.strip("|").split("|")[0].strip().strip("`"): [
            c.strip() for c in line.strip("|").split("|")
        ]
        for line in table.splitlines()
        if line.startswith("| `")
    }
    assert set(cells) == set(reports())
    for model_id, report in reports().items():
        row, s = cells[model_id], report["summary"]
        exact = s["exactness"]
        assert row[1] == str(report["targets"])
        checked = exact["returned"]["checked"] + exact["recorded"]["checked"]
        assert row[3] == f"{checked:,}"
        assert row[4] == str(exact["returned"]["violations"] + exact["recorded"]["violations"])
        recall = s["recall"]
        if recall is None:
            assert row[5] == row[6] == "-"
        else:
            assert row[5].startswith(f"{100 * recall['found_fraction']:.3g} %")
            assert row[6] == str(recall["merges"])
        assert row[-1] == f"{s['time']['ratio_boxes_to_self_only']:.2f}x"
        median = s["time"]["ms"]["scene"]["median"]
        assert row[10].split()[0] == f"{median:.3g}" or row[10].split()[0] == f"{median:,.0f}"


def test_a_single_figure_by_its_path() -> None:
    for model_id, report in reports().items():
        assert run_block("scenes", [model_id, "targets", "int"]) == f"{report['targets']:,}"
