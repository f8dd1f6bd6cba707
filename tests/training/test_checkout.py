"""checkout: a record names HEAD (with "+dirty" when service/ or training/ differ from it)
in a checkout, and "unknown" outside one."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from training.checkout import git_commit


def test_in_the_checkout_it_is_head() -> None:
    head = subprocess.run(
        ["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True
    ).stdout.strip()
    assert git_commit() in (head, f"{head}+dirty")


def test_outside_a_checkout_it_is_unknown(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("GIT_CEILING_DIRECTORIES", str(tmp_path.parent))
    assert git_commit() == "unknown"
