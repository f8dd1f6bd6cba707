"""The commit a run or report started from: what its record names as the code it ran.

Torch-free, so that the tools that write records without training (the load test, the
soak, the benchmark) name their commit the way a training run does.
"""

from __future__ import annotations

import subprocess


def git_commit() -> str:
    """HEAD, with "+dirty" when the code the run imports (service/, training/) differs from
    it; "unknown" outside a git checkout. Called when a run starts: a run takes hours, and
    HEAD may move while it does."""
    try:
        head = subprocess.run(
            ["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
        changed = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no", "--", "service", "training"],
            capture_output=True, text=True, check=True,
        ).stdout.strip()  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return f"{head}+dirty" if changed else head
