"""`python -m tools.docs [--check] [--examples]`: rewrite (or check) the figures of the
README and docs; `--examples` also re-answers their HTTP examples (tools/docs/examples.py)."""

from __future__ import annotations

import argparse
import difflib
import sys

from tools.docs.examples import write_examples
from tools.docs.pages import ROOT, rewrite


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m tools.docs",
        description="Write the figures of README.md and docs/ from the committed reports.",
    )
    parser.add_argument(
        "--check", action="store_true", help="write nothing; exit 1 with a diff if stale"
    )
    parser.add_argument(
        "--examples",
        action="store_true",
        help="also send every HTTP example to the service in process and write its answer",
    )
    args = parser.parse_args(argv)
    if args.examples and not args.check:
        for page in write_examples():
            print(f"rewrote the examples of {page.relative_to(ROOT).as_posix()}")
    changed = rewrite(check=args.check)
    for page, old, new in changed:
        name = page.relative_to(ROOT).as_posix()
        if args.check:
            sys.stdout.writelines(
                difflib.unified_diff(
                    old.splitlines(keepends=True), new.splitlines(keepends=True), name, name
                )
            )
        else:
            print(f"rewrote {name}")
    if args.check and changed:
        print(f"{len(changed)} page(s) differ from their reports: run python -m tools.docs")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
