"""The evaluation packages (training/evaluate/packages.py) made unimportable, as where they are
not installed: a finder at the head of sys.meta_path refuses `eaik` and `realtime_smm` and
every module under them with the ModuleNotFoundError a missing package raises.

In process, `refuse_evaluation_packages(monkeypatch)` for one test (modules of theirs that
earlier tests imported are forgotten, then restored); in a subprocess, `RUN_SMM_TRAIN`:
`python -c RUN_SMM_TRAIN <subcommand> <its arguments>`, run from the repository root.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import sys
from collections.abc import Sequence

import pytest

EVALUATION_MODULES = ("eaik", "realtime_smm")


class NotInstalled(importlib.abc.MetaPathFinder):
    """Refuses the evaluation packages' modules; finds nothing else."""

    def find_spec(
        self, fullname: str, path: Sequence[str] | None = None, target: object = None
    ) -> importlib.machinery.ModuleSpec | None:
        if fullname.partition(".")[0] in EVALUATION_MODULES:
            raise ModuleNotFoundError(f"No module named {fullname!r}", name=fullname)
        return None


def install() -> None:
    """For the rest of this process (a fresh one: nothing of theirs imported yet)."""
    sys.meta_path.insert(0, NotInstalled())


def refuse_evaluation_packages(monkeypatch: pytest.MonkeyPatch) -> None:
    """For one test."""
    for name in list(sys.modules):
        if name.partition(".")[0] in EVALUATION_MODULES:
            monkeypatch.delitem(sys.modules, name)
    monkeypatch.setattr(sys, "meta_path", [NotInstalled(), *sys.meta_path])


RUN_SMM_TRAIN = """
import sys
from tests.support.not_installed import EVALUATION_MODULES, install
install()
from training.cli import main
main(sys.argv[1:])
assert not any(m.partition(".")[0] in EVALUATION_MODULES for m in sys.modules)
"""
