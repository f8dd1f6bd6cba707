"""The figure blocks of the HTTP API and How it works pages (tools/docs/topics/api.py).

Each block is checked against its source read independently: `defaults` and
`defaults-table` against the manifests' JSON, `setting` against a Settings built from an
empty environment, `constant` against the module's attribute. An unknown model, path,
setting, module or constant is an error that lists the valid choices. The pages that use
the blocks are what the blocks write.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Any

import pytest

from service.config import Settings
from service.pipeline.connect import roadmap
from service.pipeline.connect.trace import walk
from tools.docs.pages import ROOT, render_page
from tools.docs.topics import api

MODELS = ROOT / "models"
PAGES = ["docs/api.md", "docs/batch.md", "docs/how-it-works.md", "docs/bad-inputs.md"]


def manifests() -> dict[str, dict[str, Any]]:
    return {
        path.parent.name: json.loads(path.read_text())
        for path in sorted(MODELS.glob("*/manifest.json"))
    }


def test_the_pages_are_what_the_blocks_write() -> None:
    for page in PAGES:
        text = (ROOT / page).read_text()
        assert render_page(text) == text, f"{page}: run python -m tools.docs"


@pytest.mark.parametrize("path", ["damping", "connectivity.trace_step_rad"])
def test_a_default_shared_by_every_model_is_one_value(path: str) -> None:
    values = set()
    for data in manifests().values():
        value: Any = data["defaults"]
        for key in path.split("."):
            value = value[key]
        values.add(value)
    (value,) = values  # the bundled models agree on these
    assert float(api.defaults(path)) == value


def test_a_default_that_differs_lists_each_value_with_its_models() -> None:
    by_value: dict[float, list[str]] = {}
    for model_id, data in manifests().items():
        by_value.setdefault(data["defaults"]["connectivity"]["delta_rad"], []).append(model_id)
    assert len(by_value) > 1
    written = api.defaults("connectivity.delta_rad")
    for value, models in by_value.items():
        assert f"{value:g} ({', '.join(models)})" in written


def test_a_default_of_named_models_only() -> None:
    data = manifests()["iiwa14-position"]
    assert api.defaults("num_samples", "iiwa14-position") == str(data["defaults"]["num_samples"])


def test_an_unknown_default_lists_the_keys_and_an_unknown_model_the_models() -> None:
    with pytest.raises(KeyError, match="trace_step_rad"):
        api.defaults("connectivity.trace_step")
    with pytest.raises(FileNotFoundError, match="planar3r-position"):
        api.defaults("damping", "ur10-position")


def table_rows(markdown: str) -> dict[str, list[str]]:
    rows = {}
    for line in markdown.splitlines()[2:]:
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        rows[cells[0].strip("`")] = cells[1:]
    return rows


def test_the_defaults_table_has_each_model_as_its_manifest_says() -> None:
    rows = table_rows(api.defaults_table())
    data = manifests()
    assert set(rows) == set(data)
    for model_id, manifest in data.items():
        joints, r, axes, orientation, axis, samples, tolerance, tolerance_rotation = rows[model_id]
        task, defaults = manifest["task"], manifest["defaults"]
        tool_axis = task.get("tool_axis")
        n = len(manifest["joints"]["names"])
        # m: the position axes, 3 for a whole orientation, 2 for a tool axis's direction.
        m = len(task["position_axes"]) + 3 * task["orientation"] + 2 * (tool_axis is not None)
        assert (int(joints), int(r)) == (n, n - m)
        assert axes.split(", ") == ["xyz"[a] for a in task["position_axes"]]
        assert orientation == ("required" if task["orientation"] else "refused")
        assert axis == ("refused" if tool_axis is None else f"required (tool axis {tool_axis})")
        assert int(samples) == defaults["num_samples"]
        assert float(tolerance) == defaults["tolerance_position_m"]
        if task["orientation"] or tool_axis is not None:
            assert float(tolerance_rotation) == defaults["tolerance_orientation_rad"]
        else:
            assert tolerance_rotation == "refused"


def test_the_defaults_table_takes_no_arguments() -> None:
    with pytest.raises(TypeError, match="no arguments"):
        api.defaults_table("planar3r-position")


@pytest.mark.parametrize(
    "name",
    ["max_num_samples", "max_batch_targets", "max_batch_samples", "max_body_bytes",
     "request_deadline_s", "batch_threads", "api_key"],
)  # fmt: skip
def test_a_setting_is_its_default_in_an_empty_environment(
    name: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    for variable in [v for v in os.environ if v.startswith("SMM_")]:
        monkeypatch.delenv(variable)
    default = getattr(Settings(), name)
    written = api.setting(name)
    if default is None:
        assert written == "unset"
    else:
        assert float(written) == default


def test_an_unknown_setting_lists_the_settings() -> None:
    with pytest.raises(KeyError, match="max_num_samples"):
        api.setting("max_samples")


def test_a_constant_is_the_module_attribute() -> None:
    assert float(api.constant("pipeline.connect.trace.walk", "meet_factor")) == walk.MEET_FACTOR
    assert float(api.constant("pipeline.connect.trace.walk", "twin_sigma")) == walk.TWIN_SIGMA
    steer = api.constant("pipeline.connect.roadmap", "roadmapsettings.steer_radius_rad")
    assert float(steer) == roadmap.RoadmapSettings.steer_radius_rad


def test_an_unknown_constant_lists_the_choices() -> None:
    with pytest.raises(KeyError, match=re.escape("pipeline.connect.trace.walk")):
        api.constant("pipeline.connect.trace.walker", "meet_factor")
    with pytest.raises(KeyError, match="MEET_FACTOR"):
        api.constant("pipeline.connect.trace.walk", "meeting")
    with pytest.raises(TypeError, match="not a number"):
        api.constant("pipeline.targets", "axis_names")


def test_numbers_are_written_as_the_pages_write_them() -> None:
    assert [api.number(v) for v in (1e-06, 0.15, 30.0, 64, True, None)] == [
        "1e-06", "0.15", "30", "64", "true", "unset",
    ]  # fmt: skip


def test_the_pages_link_only_pages_of_the_site() -> None:
    """Links are relative, to Markdown pages of docs/ (the site build checks that they
    exist and that their anchors do); repository files are code spans, not links."""
    for page in [*PAGES, "docs/examples.md", "docs/architecture.md"]:
        for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", (ROOT / page).read_text()):
            assert not target.startswith(("http", "/", "..")), f"{page}: {target}"
            assert Path(ROOT / "docs" / target).suffix == ".md", f"{page}: {target}"
