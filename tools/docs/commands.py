"""The shell commands the README and the docs show, and how each is checked.

Every command in a ```sh block is one of:

- an HTTP call (`curl ... localhost:8000/...`): `tests/docs/test_examples.py` runs it as
  written against a real server;
- a set-up command (`./scripts/serve`, `./scripts/test`): `.ci/run` runs both as written;
- marked by a comment line above it, which then applies to every command below it up to
  the next blank line or marker:
  `# long job: <why it does not run in the tests>` (training at full budget, the full
  benchmark) or `# not run by the tests: <why>` (it needs a Docker engine or a cluster);
  the figure block `commands-not-run` lists them all with their reasons;
- anything else: `tests/docs/test_commands.py` runs it as written and expects exit 0,
  against a real server where it calls localhost:8000, in the repository's root or, below
  a comment `# in a directory of your own ...`, in an empty directory.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass
from pathlib import Path

from tools.docs.blocks import block
from tools.docs.pages import ROOT, pages

SH_BLOCK = re.compile(r"```sh\n(?P<code>.*?)```", re.DOTALL)
MARKERS = {"long job": "# long job:", "not run by the tests": "# not run by the tests:"}
SETUP = ("./scripts/serve", "./scripts/test")
# A comment that tells the reader to run the commands below it in a directory of their
# own (a generated client goes into the planner's project, not this repository).
OWN_DIRECTORY = "# in a directory of your own"


@dataclass(frozen=True)
class Command:
    page: str  # relative to the repository root
    text: str  # as written, continuation lines joined by their backslash-newline
    marker: str | None  # "long job", "not run by the tests", or None
    reason: str | None
    elsewhere: bool = False  # to be run outside the repository (OWN_DIRECTORY above it)

    @property
    def kind(self) -> str:
        """http, setup, long job, not run by the tests, or run."""
        if self.marker is not None:
            return self.marker
        if self.text.startswith("curl "):
            return "http"
        if self.text in SETUP:
            return "setup"
        return "run"


def commands_in(text: str, page: str) -> list[Command]:
    """The commands of every ```sh block in `text`: a command goes on over lines that end
    in a backslash or inside an open quote (a JSON body over several lines)."""
    found = []
    for match in SH_BLOCK.finditer(text):
        marker = reason = None
        elsewhere = False
        pending: list[str] = []
        for raw in match["code"].splitlines():
            if pending:
                pending.append(raw)
                if not _complete("\n".join(pending)):
                    continue
                text = "\n".join(pending).strip()
                found.append(Command(page, text, marker, reason, elsewhere))
                pending = []
                continue
            line = raw.strip()
            if not line:
                marker = reason = None
                elsewhere = False
                continue
            if line.startswith(OWN_DIRECTORY):
                elsewhere = True
                continue
            labelled = [name for name, prefix in MARKERS.items() if line.startswith(prefix)]
            if labelled:
                marker = labelled[0]
                reason = line[len(MARKERS[marker]) :].strip()
                continue
            if line.startswith("#"):
                continue
            if _complete(line):
                found.append(Command(page, line, marker, reason, elsewhere))
            else:
                pending = [raw]
        if pending:
            raise ValueError(f"{page}: an unfinished command in a sh block: {pending[0]!r}")
    return found


def _complete(text: str) -> bool:
    """Whether `text` is a whole shell command: no trailing backslash, no open quote."""
    if text.rstrip().endswith("\\"):
        return False
    try:
        shlex.split(text, comments=True)
    except ValueError:  # "No closing quotation"
        return False
    return True


def documented_commands(root: Path = ROOT) -> list[Command]:
    """Every command of the README and the docs pages."""
    return [
        command
        for page in pages(root)
        for command in commands_in(page.read_text(), page.relative_to(root).as_posix())
    ]


@block("commands-not-run")
def commands_not_run() -> str:
    """A table of the documented commands the tests do not run, and why."""
    rows = ["| command | page | why it is not run by the tests |", "|---|---|---|"]
    for command in documented_commands():
        if command.marker is None:
            continue
        shown = command.text.split("\n", 1)[0].rstrip(" \\")
        more = " ..." if "\n" in command.text else ""
        link = command.page.removeprefix("docs/") if command.page.startswith("docs/") else None
        where = f"[{link}]({link})" if link else command.page
        reason = f"{command.marker}: {command.reason}"
        rows.append(f"| `{shown}{more}` | {where} | {reason} |")
    return "\n".join(rows)
