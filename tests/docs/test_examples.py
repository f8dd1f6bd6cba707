"""The HTTP examples of the README and the docs work as written: each `curl` runs against a
real server (the bundled models), and for an example whose answer is shown, the live answer
agrees with it.

"Agrees" means the facts the pages state about an example: the status, the model (its id
carries the hash of its files, so a retrained model shows up), the joint names and
redundancy, how many samples were drawn, how many components came back, each shown
component's fields and whether it is closed, and an error's whole `detail`. The shown
numbers (configurations, sizes, times) are one machine's answer, written by `python -m
tools.docs --examples`; another CPU's int8 arithmetic may move a sample, so they are not
compared to the digit.
"""

from __future__ import annotations

import json
import re
import subprocess
from collections.abc import Iterator
from typing import Any

import pytest

from tools.docs.commands import documented_commands
from tools.docs.examples import SHOWN_HOST, Example, abbreviate, examples
from tools.docs.pages import ROOT
from tools.local_server import LocalServer

EXAMPLES = list(examples())
HTTP = [command for command in documented_commands() if command.kind == "http"]
IN_ALL = re.compile(r"^\.\.\. (\d+) (components|points) in all$")


def run_curl(command: str, server: LocalServer) -> str:
    live = command.replace(SHOWN_HOST, server.url.removeprefix("http://"))
    result = subprocess.run(
        ["bash", "-c", live], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, f"{command}\n{result.stderr}"
    return result.stdout


def test_the_docs_show_the_examples() -> None:
    names = {example.name for example in EXAMPLES}
    assert len(names) == len(EXAMPLES), "example names are unique"
    assert len(EXAMPLES) >= 5, names
    assert all(example.shown is not None for example in EXAMPLES)


@pytest.mark.parametrize("command", HTTP, ids=[f"{c.page}:{i}" for i, c in enumerate(HTTP)])
def test_every_curl_of_the_docs_runs_against_a_real_server(
    command: Any, server: LocalServer
) -> None:
    output = run_curl(command.text, server)
    json.loads(output)  # every documented call answers JSON


@pytest.mark.parametrize("example", EXAMPLES, ids=[e.name for e in EXAMPLES])
def test_the_shown_answer_agrees_with_the_live_one(example: Example, server: LocalServer) -> None:
    live = abbreviate(
        json.loads(run_curl(example.command, server)), example.components, example.path_points
    )
    problems = list(disagreements(example.shown, live))
    assert not problems, (
        f"{example.page.name}: example {example.name} no longer shows the service's answer "
        "(python -m tools.docs --examples rewrites it):\n" + "\n".join(problems)
    )


STATED = {
    "status",
    "robot",
    "task",
    "model",
    "joint_names",
    "redundancy",
    "sampled",
    "closed",
    "id",
    "index",
    "detail",
}


def disagreements(shown: Any, live: Any, where: str = "") -> Iterator[str]:
    """Where `live` contradicts a fact `shown` states (see the module's docstring)."""
    if isinstance(shown, dict):
        if not isinstance(live, dict):
            yield f"{where}: shown an object, got {type(live).__name__}"
            return
        if set(shown) != set(live):
            yield f"{where}: fields {sorted(shown)} shown, {sorted(live)} answered"
        for key in shown.keys() & live.keys():
            if key in STATED:
                if shown[key] != live[key]:
                    yield f"{where}.{key}: shown {shown[key]!r}, answered {live[key]!r}"
            elif key != "timings_ms":
                yield from disagreements(shown[key], live[key], f"{where}.{key}")
    elif isinstance(shown, list):
        if not isinstance(live, list):
            yield f"{where}: shown a list, got {type(live).__name__}"
            return
        (n_shown, kind), (n_live, _) = _count(shown), _count(live)
        if kind != "points" and n_shown != n_live:  # a path's length is a number shown
            yield f"{where}: {n_shown} {kind or 'items'} shown, {n_live} answered"
        for a, b in zip(shown, live, strict=False):
            if isinstance(a, dict | list):
                yield from disagreements(a, b, f"{where}[]")


def _count(items: list[Any]) -> tuple[int, str | None]:
    """How many items a list stands for: N of a closing "... N components in all"."""
    if items and isinstance(items[-1], str) and (match := IN_ALL.match(items[-1])):
        return int(match[1]), match[2]
    return len(items), None


def test_disagreements_finds_a_changed_fact() -> None:
    """The comparison fails where it should: a count of components, a status, a model."""
    shown = {
        "status": "ok",
        "model": "m@1",
        "timings_ms": {"total": 1.0},
        "components": [{"id": 0, "closed": True, "size": 3}, "... 5 components in all"],
    }
    same = {
        "status": "ok",
        "model": "m@1",
        "timings_ms": {"total": 9.0},
        "components": [{"id": 0, "closed": True, "size": 4}, "... 5 components in all"],
    }
    assert not list(disagreements(shown, same))
    fewer = {
        **same,
        "components": [{"id": 0, "closed": True, "size": 4}, "... 4 components in all"],
    }
    assert list(disagreements(shown, fewer))
    assert list(disagreements(shown, {**same, "status": "no_solution"}))
    assert list(disagreements(shown, {**same, "model": "m@2"}))
    opened = {
        **same,
        "components": [{"id": 0, "closed": False, "size": 4}, "... 5 components in all"],
    }
    assert list(disagreements(shown, opened))
