"""Figure blocks of the HTTP API and How it works pages: the values a page states that the
code or the bundled models' manifests define, so a page cannot drift from them.

    <!-- figures: defaults-table -->                         the bundled models' request defaults
    <!-- figures: defaults connectivity.trace_step_rad -->  one manifest default, every model
    <!-- figures: setting max_num_samples -->              a setting's default (service/config.py)
    <!-- figures: constant pipeline.connect.trace.walk meet_factor --> a service module constant

Marker words are lower case, so `setting` and `constant` match names case-insensitively.
"""

from __future__ import annotations

import importlib
from typing import Any

from service.manifest import TaskSpec
from tools.docs import sources
from tools.docs.blocks import block
from tools.docs.sources import ROOT, manifest, model_ids

AXIS_NAMES = ("x", "y", "z")
SERVICE = ROOT / "service"


def number(value: Any) -> str:
    """A value as the pages write it: floats by `:g` (1e-06, 0.15, 30), booleans in JSON's
    spelling, None as `unset`."""
    if value is None:
        return "unset"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def redundancy(data: dict[str, Any]) -> int:
    """n - m of a manifest: joints less the task's coordinates (`TaskSpec.dimension`)."""
    return len(data["joints"]["names"]) - TaskSpec.model_validate(data["task"]).dimension


@block("defaults")
def defaults(path: str, *models: str) -> str:
    """The manifest default at the dotted `path` under `defaults` (e.g.
    `connectivity.trace_step_rad`), over every bundled model or the `models` named: one
    value when they agree, else each value with its models, `0.1 (a, b), 0.3 (c)`."""
    chosen = list(models) or model_ids()
    by_value: dict[str, list[str]] = {}
    for model_id in chosen:
        value = sources.lookup(manifest(model_id)["defaults"], path, f"{model_id} defaults")
        by_value.setdefault(number(value), []).append(model_id)
    if len(by_value) == 1:
        return next(iter(by_value))
    return ", ".join(f"{value} ({', '.join(ids)})" for value, ids in by_value.items())


@block("defaults-table")
def defaults_table(*arguments: str) -> str:
    """One row per bundled model: its joints, redundancy, what `target` takes, and the
    defaults a request leaves out (num_samples, tolerances)."""
    if arguments:
        raise TypeError(f"defaults-table takes no arguments, got {list(arguments)}")
    rows = [
        "| model | joints | r | `target.position` | `target.orientation` | `target.axis` "
        "| `num_samples` | `tolerance.position` (m) | `tolerance.orientation` (rad) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for model_id in model_ids():
        data = manifest(model_id)
        task, default = TaskSpec.model_validate(data["task"]), data["defaults"]
        axes = ", ".join(AXIS_NAMES[a] for a in task.position_axes)
        orientation = "required" if task.orientation else "refused"
        axis = "refused" if task.tool_axis is None else f"required (tool axis {task.tool_axis})"
        tolerance_orientation = (
            number(default["tolerance_orientation_rad"]) if task.orientation_rows else "refused"
        )
        rows.append(
            f"| `{model_id}` | {len(data['joints']['names'])} | {redundancy(data)} "
            f"| {axes} | {orientation} | {axis} | {default['num_samples']} "
            f"| {number(default['tolerance_position_m'])} | {tolerance_orientation} |"
        )
    return "\n".join(rows)


@block("setting")
def setting(name: str) -> str:
    """The default of the setting `name` (a field of service/config.py's Settings, its
    variable SMM_<NAME>)."""
    from service.config import Settings

    fields = Settings.model_fields
    if name not in fields:
        raise KeyError(f"no setting {name!r}; the settings are: {sorted(fields)}")
    return number(fields[name].default)


def _service_modules() -> list[str]:
    """Every module of `service/`, as `constant` names it (`pipeline.connect.trace.walk`)."""
    return sorted(
        ".".join(p.relative_to(SERVICE).with_suffix("").parts)
        for p in SERVICE.rglob("*.py")
        if p.name != "__init__.py"
    )


@block("constant")
def constant(module: str, name: str) -> str:
    """The value of `name` in `service.<module>`, matched without case: a module constant
    (`meet_factor` -> MEET_FACTOR) or a dotted class default
    (`roadmapsettings.steer_radius_rad`)."""
    modules = _service_modules()
    if module not in modules:
        raise KeyError(f"no module service.{module}; there are: {modules}")
    value: Any = importlib.import_module(f"service.{module}")
    walked = f"service.{module}"
    for part in name.split("."):
        matches = [attribute for attribute in vars(value) if attribute.lower() == part]
        if not matches:
            names = sorted(a for a in vars(value) if not a.startswith("_"))
            raise KeyError(f"{walked} has no {part!r}; it has: {names}")
        value = getattr(value, matches[0])
        walked = f"{walked}.{matches[0]}"
    if not isinstance(value, int | float):
        raise TypeError(f"{walked} is not a number: {value!r}")
    return number(value)
