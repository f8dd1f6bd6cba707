"""rendering: the committed reports' Markdown is what rendering their JSON gives, and
Table 2 sets each method's errors (raw for FM and ODE, returned for the others) beside
the paper's figures.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from training.evaluate.rendering import PAPER_TABLE_2, markdown, table_2
from training.evaluate.report import REPORTS_DIR

REPORTS = sorted(REPORTS_DIR.glob("*.json"))


@pytest.mark.parametrize("path", REPORTS, ids=[p.stem for p in REPORTS])
def test_committed_markdown_is_the_rendering_of_the_committed_json(path: Path) -> None:
    assert markdown(path.stem, json.loads(path.read_text())) == path.with_suffix(".md").read_text()


def _summary(raw_pct: float, returned_pct: float) -> dict[str, object]:
    def errors(pct: float) -> dict[str, float | None]:
        return {"e_p_pct": pct, "e_o_pct": None, "e_pct": pct, "mm": pct, "deg": None}

    return {"raw": errors(raw_pct), "returned": errors(returned_pct), "median_time_ms": 5.0}


def test_table_2_takes_raw_errors_for_fm_and_ode_and_quotes_the_paper() -> None:
    report = {"methods": {name: _summary(1.5, 2.5e-9) for name in ("FM", "FM + DLS", "ODE")}}
    text = table_2({"planar3r-position": report})
    paper_fm_e_p_pct = PAPER_TABLE_2["planar3r-position"]["FM"][0]
    assert f"| planar3r-position | FM | 1.5 | - | 1.5 | 5 | {paper_fm_e_p_pct:.3g} |" in text
    assert "| planar3r-position | FM + DLS | 2.5e-09 |" in text
    assert "| planar3r-position | ODE | 1.5 |" in text
