"""Figure blocks of the Deployment page, from docs/container.json (the container test's run).

    <!-- figures: container-table -->             image size, cold start, test time
    <!-- figures: container-first-requests -->    each model's first answer after start-up
    <!-- figures: container-checks -->            every check the container test made
    <!-- figures: container read_only_peak_rss_bytes -->   one figure, in its unit

Sizes are written as `docker images` shows them (decimal MB), memory in MiB, times in s
or ms as the JSON key names them.
"""

from __future__ import annotations

from typing import Any

from tools.docs import sources
from tools.docs.blocks import block

MB = 1e6
MIB = 2**20


def unit(key: str, value: Any) -> str:
    """A container figure in the unit its key names: *_bytes of an image in MB, of memory
    (rss) in MiB; *_s in s; *_ms in ms."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return str(value)
    if key.endswith("_bytes"):
        if "rss" in key:
            return f"{value / MIB:.0f} MiB"
        return f"{value / MB:.0f} MB"
    if key.endswith("_s"):
        return f"{value:g} s"
    if key.endswith("_ms"):
        return f"{value:g} ms"
    return f"{value:g}"


def figure(path: str) -> tuple[str, Any]:
    """The container record at a dotted path, and the key that names its unit; an unknown
    key lists those at its level."""
    value = sources.lookup(sources.container(), path, "docs/container.json")
    walked = path.split(".")
    unit_key = walked[-2] if len(walked) > 1 and walked[-2].endswith(("_ms", "_s")) else walked[-1]
    return unit_key, value


@block("container")
def container_figure(path: str) -> str:
    """One figure of docs/container.json in its unit, e.g. `image_bytes` (MB),
    `read_only_peak_rss_bytes` (MiB), `cold_start_s`, `timings.build_s`,
    `first_request_ms.iiwa14-pose`."""
    key, value = figure(path)
    return unit(key, value)


@block("container-table")
def container_table(*arguments: str) -> str:
    """The image's size (the base's and ours), the cold start and the run to /readyz, the
    read-only run's memory, and the container test's time."""
    if arguments:
        raise TypeError(f"container-table takes no arguments, got {list(arguments)}")
    record = sources.container()
    timings = record["timings"]
    header = ["image", "of which base", "of which ours (venv + models)",
              "cold start: process start to `/readyz` 200", "`buildah run` to `/readyz` 200",
              "RSS ready / peak (read-only run)", "container test"]  # fmt: skip
    row = [
        unit("image_bytes", record["image_bytes"]),
        unit("base_bytes", record["base_bytes"]),
        unit("added_bytes", record["added_bytes"]),
        unit("cold_start_s", record["cold_start_s"]),
        unit("run_to_ready_s", record["run_to_ready_s"]),
        f"{unit('rss_bytes', record['read_only_rss_ready_bytes'])} / "
        f"{unit('rss_bytes', record['read_only_peak_rss_bytes'])}",
        f"{timings['total_s']:g} s (build {timings['build_s']:g} s, run and checks "
        f"{timings['run_and_checks_s']:g} s, read-only run {timings['read_only_run_s']:g} s)",
    ]
    return (
        "| " + " | ".join(header) + " |\n|" + "---|" * len(header) + "\n| " + " | ".join(row) + " |"
    )


@block("container-first-requests")
def container_first_requests(*arguments: str) -> str:
    """Each model's first `POST /smm` after start-up, in ms, as one phrase."""
    if arguments:
        raise TypeError(f"container-first-requests takes no arguments, got {list(arguments)}")
    first = sources.container()["first_request_ms"]
    return ", ".join(f"`{model}` {ms:g} ms" for model, ms in first.items())


@block("container-checks")
def container_checks(*arguments: str) -> str:
    """Every check of the container test's run, passed or failed, with what it saw."""
    if arguments:
        raise TypeError(f"container-checks takes no arguments, got {list(arguments)}")
    lines = ["| check | passed | what it saw |", "|---|---|---|"]
    for check in sources.container()["checks"]:
        detail = check["detail"].replace("|", "\\|")
        lines.append(f"| {check['name']} | {'yes' if check['ok'] else '**no**'} | {detail} |")
    return "\n".join(lines)
