"""The HTTP examples of the docs: each shown request with the service's real answer.

A page wraps an example in markers, around a ```sh block holding one `curl` to
localhost:8000 and the ```json block that shows its answer:

    <!-- example: planar-two-loops -->
    ```sh
    curl -s -X POST localhost:8000/smm -H 'content-type: application/json' -d '{...}'
    ```
    ... prose ...
    ```json
    {... the answer, abbreviated ...}
    ```
    <!-- /example -->

`python -m tools.docs --examples` sends each request to the service in process (the
bundled models) and writes its answer into the json block, abbreviated by `abbreviate`:
numbers to 4 decimals (4 significant digits below 1e-3; times to 0.1 ms), at most `components=K`
components (2 unless the marker says) and `path=P` entries of each path and of each
roadmap's nodes and edges, the rest summarised in a string. `tests/docs/test_examples.py`
runs every curl as written against a real server and checks that its answer agrees with
the one shown.
"""

from __future__ import annotations

import json
import re
import shlex
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tools.docs.pages import ROOT, pages

EXAMPLE = re.compile(
    r"<!-- example: (?P<spec>[a-z0-9][a-z0-9 =_-]*?) -->(?P<body>.*?)<!-- /example -->",
    re.DOTALL,
)
SH_BLOCK = re.compile(r"```sh\n(?P<code>.*?)```", re.DOTALL)
JSON_BLOCK = re.compile(r"```json\n(?P<code>.*?)```", re.DOTALL)
SHOWN_HOST = "localhost:8000"


@dataclass(frozen=True)
class Example:
    """One example: its page, name, the curl as written, the request, the shown answer."""

    page: Path
    name: str
    components: int  # components shown at most
    path_points: int  # points shown of each path at most
    command: str  # the curl command as the page shows it
    method: str
    route: str  # e.g. /smm
    body: dict[str, Any]
    shown: Any | None  # the json block, parsed; None when the page shows none


def parse_curl(command: str) -> tuple[str, str, dict[str, Any]]:
    """(method, route, body) of a `curl ... localhost:8000/<route> ... -d '<json>'`."""
    words = shlex.split(command.replace("\\\n", " "))
    if not words or words[0] != "curl":
        raise ValueError(f"an example's command must be one curl, got: {command[:60]!r}")
    method, route, body = "GET", "", None
    for i, word in enumerate(words):
        if word == "-X":
            method = words[i + 1]
        elif word in ("-d", "--data"):
            body = json.loads(words[i + 1])
        elif word.startswith(SHOWN_HOST):
            route = word[len(SHOWN_HOST) :]
    if not route:
        raise ValueError(f"an example's curl must call {SHOWN_HOST}, got: {command[:60]!r}")
    if body is not None and method == "GET":
        method = "POST"
    return method, route, body or {}


def examples(page_paths: list[Path] | None = None) -> Iterator[Example]:
    """Every marked example of the README and the docs."""
    for page in page_paths if page_paths is not None else pages():
        yield from examples_in(page, page.read_text())


def examples_in(page: Path, text: str) -> Iterator[Example]:
    """The marked examples in `text`, a part or the whole of `page`."""
    for match in EXAMPLE.finditer(text):
        name, *options = match["spec"].split()
        settings = dict(option.split("=", 1) for option in options)
        sh = SH_BLOCK.findall(match["body"])
        if len(sh) != 1:
            raise ValueError(f"{page.name}: example {name} needs exactly one ```sh block")
        command = sh[0].strip()
        method, route, body = parse_curl(command)
        shown = JSON_BLOCK.findall(match["body"])
        yield Example(
            page=page,
            name=name,
            components=int(settings.get("components", 2)),
            path_points=int(settings.get("path", 2)),
            command=command,
            method=method,
            route=route,
            body=body,
            shown=json.loads(shown[-1]) if shown else None,
        )


def _number(x: float) -> float:
    if x == 0 or abs(x) >= 1e-3:
        return round(x, 4)
    return float(f"{x:.4g}")


# The lists shown by their first `path=P` entries, and what the rest are called.
LONG_LISTS = {"path": "points", "nodes": "nodes", "edges": "edges"}


def abbreviate(answer: Any, components: int = 2, path_points: int = 2) -> Any:
    """`answer` as the docs show it: rounded numbers, the first components and path points."""

    def walk(value: Any, key: str = "") -> Any:
        if isinstance(value, bool) or value is None or isinstance(value, int | str):
            return value
        if isinstance(value, float):
            return _number(value)
        if isinstance(value, list):
            if key == "components" and len(value) > components:
                shown = [walk(v) for v in value[:components]]
                return [*shown, f"... {len(value)} components in all"]
            if key in LONG_LISTS and len(value) > path_points:
                shown = [walk(v) for v in value[:path_points]]
                return [*shown, f"... {len(value)} {LONG_LISTS[key]} in all"]
            return [walk(v) for v in value]
        if key == "timings_ms":  # one run's times, to a tenth of a millisecond
            return {k: round(v, 1) for k, v in value.items()}
        return {k: walk(v, k) for k, v in value.items()}

    return walk(answer)


def dump(value: Any, indent: int = 0) -> str:
    """JSON with every list of numbers on one line, as a reader scans configurations."""
    pad, inner = "  " * indent, "  " * (indent + 1)
    if isinstance(value, dict):
        if not value:
            return "{}"
        items = [f"{inner}{json.dumps(k)}: {dump(v, indent + 1)}" for k, v in value.items()]
        if all(not isinstance(v, dict | list) or _flat(v) for v in value.values()):
            line = "{" + ", ".join(f"{json.dumps(k)}: {dump(v)}" for k, v in value.items()) + "}"
            if len(line) + len(pad) <= 100:
                return line
        return "{\n" + ",\n".join(items) + f"\n{pad}}}"
    if isinstance(value, list):
        if _flat(value):
            return "[" + ", ".join(json.dumps(v) for v in value) + "]"
        return "[\n" + ",\n".join(f"{inner}{dump(v, indent + 1)}" for v in value) + f"\n{pad}]"
    return json.dumps(value)


def _flat(value: Any) -> bool:
    return isinstance(value, list) and all(not isinstance(v, dict | list) for v in value)


def answer_in_process(example: Example, client: Any) -> Any:
    """The service's answer to `example`'s request, from a TestClient over the bundled models."""
    response = client.request(example.method, example.route, json=example.body or None)
    return response.json()


def write_examples(root: Path = ROOT) -> list[Path]:
    """Rewrite every example's json block with the service's answer; the pages changed."""
    from fastapi.testclient import TestClient

    from service.config import Settings
    from service.main import create_app

    changed = []
    with TestClient(create_app(Settings())) as client:
        for page in pages(root):
            text = page.read_text()

            def replace(match: re.Match[str], page: Path = page) -> str:
                (example,) = examples_in(page, match.group(0))
                answer = abbreviate(
                    answer_in_process(example, client), example.components, example.path_points
                )
                block = f"```json\n{dump(answer)}\n```"
                body = match["body"]
                found = list(JSON_BLOCK.finditer(body))
                if found:
                    last = found[-1]
                    body = body[: last.start()] + block + body[last.end() :]
                else:
                    body = body.rstrip("\n") + f"\n\n{block}\n"
                return f"<!-- example: {match['spec']} -->{body}<!-- /example -->"

            new = EXAMPLE.sub(replace, text)
            if new != text:
                page.write_text(new)
                changed.append(page)
    return changed
