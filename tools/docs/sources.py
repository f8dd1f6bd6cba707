"""The committed reports that figures are written from, read as JSON."""

from __future__ import annotations

import json
from collections.abc import Mapping
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


def report(name: str) -> dict[str, Any]:
    """docs/reports/<name>.json: a model's evaluation against exact ground truth (or, as
    `reflow/<name>`, one with its reflowed sampler)."""
    return _existing(REPORTS / f"{name}.json", names(REPORTS))


def benchmark(name: str = "benchmark") -> dict[str, Any]:
    """docs/benchmark/<name>.json: the speed benchmark, the load test or a judge's record."""
    return _existing(BENCHMARK / f"{name}.json", names(BENCHMARK))


def names(folder: Path) -> list[str]:
    """Every JSON report under `folder`, as the functions above name it (no .json)."""
    return sorted(p.relative_to(folder).with_suffix("").as_posix() for p in folder.rglob("*.json"))


def judged() -> list[str]:
    """The judge's records, docs/benchmark/judge-<name>.json, by <name>."""
    return sorted(n.removeprefix("judge-") for n in names(BENCHMARK) if n.startswith("judge-"))


def manifest(model_id: str) -> dict[str, Any]:
    """models/<model_id>/manifest.json: the served model's provenance and quality."""
    return _existing(MODELS / model_id / "manifest.json", model_ids())


def collision(model_id: str) -> dict[str, Any]:
    """models/<model_id>/collision.json: the model's bodies as spheres, the pairs not checked."""
    return _existing(MODELS / model_id / "collision.json", model_ids())


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


def lookup(data: Any, path: str, where: str, aliases: Mapping[str, str] | None = None) -> Any:
    """The value at the dotted `path` of `data` (`where` names it in errors). A key with a
    dot in it (`within_0.1`) is matched whole, the longest first; a number indexes a list;
    an alias (`restart`) stands for the key it names. An unknown step lists the valid ones,
    aliases included."""
    aliases = aliases or {}
    parts = path.split(".")
    value: Any = data
    walked: list[str] = []
    while parts:
        at = ".".join(walked) or "the top level"
        if isinstance(value, list):
            if not parts[0].isdigit() or int(parts[0]) >= len(value):
                raise KeyError(
                    f"{where}: {at} is a list of {len(value)}; {parts[0]!r} is not an index of it"
                )
            value, step, parts = value[int(parts[0])], parts[0], parts[1:]
        elif isinstance(value, dict):
            for length in range(len(parts), 0, -1):
                key = ".".join(parts[:length])
                key = key if key in value else aliases.get(key, key)
                if key in value:
                    value, step, parts = value[key], key, parts[length:]
                    break
            else:
                named = sorted(alias for alias, key in aliases.items() if key in value)
                choices = sorted(map(str, value)) + named
                raise KeyError(f"{where}: no {parts[0]!r} at {at}; there are: {choices}")
        else:
            raise KeyError(f"{where}: {at} is a value, not a mapping or a list")
        walked.append(step)
    return value
