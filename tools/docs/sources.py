"""The committed reports that figures are written from, read as JSON."""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
REPORTS = ROOT / "docs" / "reports"
BENCHMARK = ROOT / "docs" / "benchmark"
MODELS = ROOT / "models"


@cache
def _read(path: Path) -> Any:
    return json.loads(path.read_text())


def report(model_id: str) -> dict[str, Any]:
    """docs/reports/<model_id>.json: the evaluation against exact ground truth."""
    return _existing(REPORTS / f"{model_id}.json", sorted(p.stem for p in REPORTS.glob("*.json")))


def benchmark(name: str = "benchmark") -> dict[str, Any]:
    """docs/benchmark/<name>.json: the speed benchmark (or a judge's record)."""
    return _existing(BENCHMARK / f"{name}.json", sorted(p.stem for p in BENCHMARK.glob("*.json")))


def manifest(model_id: str) -> dict[str, Any]:
    """models/<model_id>/manifest.json: the served model's provenance and quality."""
    return _existing(MODELS / model_id / "manifest.json", model_ids())


def container() -> dict[str, Any]:
    """docs/container.json: the container test's figures."""
    return _read(ROOT / "docs" / "container.json")


def model_ids() -> list[str]:
    """Every bundled model, in directory order."""
    return sorted(p.parent.name for p in MODELS.glob("*/manifest.json"))


def _existing(path: Path, choices: list[str]) -> dict[str, Any]:
    if not path.exists():
        raise FileNotFoundError(f"{path.relative_to(ROOT)} does not exist; there are: {choices}")
    return _read(path)
