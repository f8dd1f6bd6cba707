"""The deployment blocks (tools/docs/topics/deployment.py) write what docs/container.json,
the container test's record, holds: sizes in decimal MB as `docker images` shows them,
memory in MiB, times in s or ms as their keys name them; the table's cells and every
check are the record's own; an unknown key or an argument where none is taken names the
valid choices; and the facts docs/deployment.md states in words (every check passed, the
peak memory under the pod's limit) hold in the record."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import yaml

from tools.docs.blocks import run_block

ROOT = Path(__file__).resolve().parents[2]
RECORD: dict[str, Any] = json.loads((ROOT / "docs" / "container.json").read_text())


def body(table: str) -> list[list[str]]:
    lines = [line for line in table.splitlines() if line.startswith("|")]
    return [[c.strip() for c in line.strip("|").split("|")] for line in lines[2:]]


def test_one_figure_is_written_in_its_keys_unit() -> None:
    assert run_block("container", ["image_bytes"]) == f"{RECORD['image_bytes'] / 1e6:.0f} MB"
    peak = RECORD["read_only_peak_rss_bytes"]
    assert run_block("container", ["read_only_peak_rss_bytes"]) == f"{peak / 2**20:.0f} MiB"
    assert run_block("container", ["cold_start_s"]) == f"{RECORD['cold_start_s']:g} s"
    assert run_block("container", ["timings.build_s"]) == f"{RECORD['timings']['build_s']:g} s"
    first = RECORD["first_request_ms"]["iiwa14-pose"]
    assert run_block("container", ["first_request_ms.iiwa14-pose"]) == f"{first:g} ms"
    assert run_block("container", ["machine"]) == RECORD["machine"]


def test_an_unknown_key_lists_the_keys_there_are() -> None:
    with pytest.raises(KeyError, match=r"there are: \[.*'image_bytes'"):
        run_block("container", ["image_size"])
    with pytest.raises(
        KeyError, match=r"no 'ur10' at first_request_ms; there are: \[.*'iiwa14-pose'"
    ):
        run_block("container", ["first_request_ms.ur10"])
    for name in ("container-table", "container-checks", "container-first-requests"):
        with pytest.raises(TypeError, match="takes no arguments"):
            run_block(name, ["extra"])


def test_the_table_is_the_records_sizes_start_and_timings() -> None:
    (row,) = body(run_block("container-table", []))
    assert row[:3] == [
        f"{RECORD[key] / 1e6:.0f} MB" for key in ("image_bytes", "base_bytes", "added_bytes")
    ]
    assert row[3] == f"{RECORD['cold_start_s']:g} s" and row[4] == f"{RECORD['run_to_ready_s']:g} s"
    ready, peak = RECORD["read_only_rss_ready_bytes"], RECORD["read_only_peak_rss_bytes"]
    assert row[5] == f"{ready / 2**20:.0f} MiB / {peak / 2**20:.0f} MiB"
    assert row[6].startswith(f"{RECORD['timings']['total_s']:g} s (build ")


def test_the_first_requests_are_every_models() -> None:
    text = run_block("container-first-requests", [])
    for model_id, ms in RECORD["first_request_ms"].items():
        assert f"`{model_id}` {ms:g} ms" in text


def test_every_check_is_listed_and_passed() -> None:
    rows = body(run_block("container-checks", []))
    assert [row[0] for row in rows] == [check["name"] for check in RECORD["checks"]]
    # docs/deployment.md presents a run in which every check passed.
    assert all(row[1] == "yes" for row in rows) and all(c["ok"] for c in RECORD["checks"])


def test_the_peak_memory_is_under_the_pods_limit() -> None:
    # docs/deployment.md: the read-only run's peak stays under the pod's memory limit.
    deployment = yaml.safe_load((ROOT / "deploy" / "base" / "deployment.yaml").read_text())
    limit = deployment["spec"]["template"]["spec"]["containers"][0]["resources"]["limits"]
    assert limit["memory"] == "1Gi"
    assert RECORD["read_only_peak_rss_bytes"] < 2**30
