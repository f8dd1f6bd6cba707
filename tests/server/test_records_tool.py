"""tools.records: a record names the command that wrote it, with the arguments given to the
tool's main (or the process's own when none are given), and is written as indented JSON
that reads back as the record and ends in a newline."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from tools.records import command_line, write_record


def test_the_command_names_the_tool_and_its_arguments(monkeypatch: pytest.MonkeyPatch) -> None:
    assert command_line("tools.soak", ["--clients", "4"]) == "python -m tools.soak --clients 4"
    assert command_line("tools.soak", []) == "python -m tools.soak"
    monkeypatch.setattr(sys, "argv", ["soak.py", "--duration-s", "60"])
    assert command_line("tools.soak") == "python -m tools.soak --duration-s 60"


def test_a_record_reads_back_and_ends_in_a_newline(tmp_path: Path) -> None:
    record = {"command": "python -m tools.load", "figures": {"p99_ms": 12.5}, "runs": [1, 2]}
    path = tmp_path / "record.json"
    write_record(path, record)
    text = path.read_text()
    assert json.loads(text) == record
    assert text.endswith("}\n") and '\n "figures": {' in text  # indent 1
