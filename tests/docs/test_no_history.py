"""History lives in CHANGELOG.md only: no tracked file but the changelog speaks of issue
numbers or sessions, which say nothing to a reader of the code or the docs."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
# Assembled from parts, so that this file does not match itself.
WORDS = re.compile(
    "|".join(("this " + "session", "previous " + "session", "issue " + "[0-9]+")), re.I
)


def tracked_text_files() -> list[Path]:
    names = subprocess.run(
        ["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True
    ).stdout.split(b"\0")
    files = []
    for name in names:
        path = ROOT / name.decode()
        if not name or not path.is_file() or path.name == "CHANGELOG.md":
            continue
        data = path.read_bytes()
        if b"\0" not in data[:8192]:  # not a binary (ONNX, PNG)
            files.append(path)
    return files


def test_no_tracked_file_but_the_changelog_mentions_issues_or_sessions() -> None:
    found = [
        f"{path.relative_to(ROOT)}:{number}: {line.strip()[:100]}"
        for path in tracked_text_files()
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1)
        if WORDS.search(line)
    ]
    assert not found, "history belongs in CHANGELOG.md:\n" + "\n".join(found)


def test_the_check_finds_what_it_looks_for() -> None:
    """The pattern matches the phrases it exists to keep out (so the test can fail)."""
    session = "Session"  # the phrases are assembled too, so this file holds none of them
    for phrase in (
        f"as in this {session}",
        f"the previous {session.lower()}'s run",
        f"see Issue {14}",
    ):
        assert WORDS.search(phrase), phrase
    assert not WORDS.search("an issue with the Jacobian; the ONNX sessions")
