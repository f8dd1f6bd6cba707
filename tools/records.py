"""How a tool writes its record: the command that made it, and the JSON file.

Every committed record (docs/benchmark/*.json) names the command that wrote it, so the
docs can print it beside the figures and anyone can run it again.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any


def command_line(tool: str, argv: Sequence[str] | None = None) -> str:
    """`python -m <tool>` and its arguments: `argv` as given to the tool's `main`, or the
    process's own when None."""
    return " ".join([f"python -m {tool}", *(sys.argv[1:] if argv is None else argv)])


def write_record(path: str | Path, record: dict[str, Any]) -> None:
    """The record as indented JSON, ending in a newline."""
    Path(path).write_text(json.dumps(record, indent=1) + "\n")
