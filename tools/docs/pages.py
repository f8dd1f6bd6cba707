"""Finding the figure markers in the pages and writing the blocks between them."""

from __future__ import annotations

import re
from pathlib import Path

from tools.docs.blocks import run_block

ROOT = Path(__file__).resolve().parents[2]
# The pages whose figures are generated: the README and the documentation site. The
# reports under docs/reports and docs/benchmark are written whole by their own commands.
GENERATED_ELSEWHERE = ("docs/reports/", "docs/benchmark/")

MARKER = re.compile(
    r"<!-- figures: (?P<spec>[a-z0-9][a-z0-9 ._/=-]*?) -->(?P<body>.*?)<!-- /figures -->",
    re.DOTALL,
)


def pages(root: Path = ROOT) -> list[Path]:
    """README.md and every Markdown page of docs/ but the reports."""
    found = [root / "README.md", *sorted((root / "docs").rglob("*.md"))]
    return [
        page
        for page in found
        if page.exists()
        and not any(page.relative_to(root).as_posix().startswith(p) for p in GENERATED_ELSEWHERE)
    ]


def render_page(text: str) -> str:
    """`text` with every block between its markers rewritten from the reports."""

    def replace(match: re.Match[str]) -> str:
        name, *arguments = match["spec"].split()
        content = run_block(name, arguments).strip("\n")
        if match["body"].startswith("\n"):  # a block on its own lines
            content = f"\n{content}\n"
        return f"<!-- figures: {match['spec']} -->{content}<!-- /figures -->"

    return MARKER.sub(replace, text)


def rewrite(root: Path = ROOT, check: bool = False) -> list[tuple[Path, str, str]]:
    """Re-render every page; returns (page, old, new) for each page that differs, and
    writes the new text unless `check`."""
    changed = []
    for page in pages(root):
        old = page.read_text()
        new = render_page(old)
        if new != old:
            changed.append((page, old, new))
            if not check:
                page.write_text(new)
    return changed
