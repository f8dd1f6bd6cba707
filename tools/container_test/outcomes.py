"""The outcome of each check, in order: a failing check is recorded and the run goes on."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass, field


@dataclass
class Checks:
    """Each check's outcome, in order; a failing check is recorded and the run goes on."""

    results: list[tuple[str, bool, str]] = field(default_factory=list)

    @contextlib.contextmanager
    def check(self, name: str) -> Iterator[dict[str, str]]:
        note: dict[str, str] = {}
        try:
            yield note
        except Exception as error:  # a failed check, whatever raised it
            self.results.append((name, False, f"{type(error).__name__}: {error}"))
            print(f"FAIL {name}: {type(error).__name__}: {error}", flush=True)
        else:
            self.results.append((name, True, note.get("detail", "")))
            print(
                f"ok   {name}" + (f": {note['detail']}" if note.get("detail") else ""), flush=True
            )

    @property
    def failed(self) -> list[str]:
        return [name for name, ok, _ in self.results if not ok]
