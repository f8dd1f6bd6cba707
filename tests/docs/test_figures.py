"""Every generated figure of the README and the docs is what `python -m tools.docs` writes
from the committed reports: the pages as committed are its output, so a figure edited by
hand, or a report re-run without its pages re-written, fails."""

from __future__ import annotations

import pytest

from tools.docs.blocks import BLOCKS, UnknownBlockError, block, load_topics
from tools.docs.pages import ROOT, pages, render_page, rewrite


def test_the_committed_pages_are_what_the_reports_give() -> None:
    changed = rewrite(check=True)
    assert not changed, (
        "stale figures in "
        + ", ".join(str(page.relative_to(ROOT)) for page, _, _ in changed)
        + ": run python -m tools.docs"
    )


def test_every_marker_names_a_registered_block() -> None:
    load_topics()
    for page in pages():
        render_page(page.read_text())  # raises UnknownBlockError otherwise


@pytest.fixture
def answer_block() -> object:
    @block("test-answer")
    def answer(value: str = "42") -> str:
        return f"the answer is {value}"

    yield answer
    del BLOCKS["test-answer"]


def test_a_block_is_rewritten_between_its_markers(answer_block: object) -> None:
    inline = "say <!-- figures: test-answer 7 -->stale<!-- /figures --> now"
    assert (
        render_page(inline)
        == "say <!-- figures: test-answer 7 -->the answer is 7<!-- /figures --> now"
    )
    own_lines = "<!-- figures: test-answer -->\nold\ntext\n<!-- /figures -->"
    assert (
        render_page(own_lines)
        == "<!-- figures: test-answer -->\nthe answer is 42\n<!-- /figures -->"
    )


def test_an_unknown_block_lists_the_valid_ones() -> None:
    with pytest.raises(UnknownBlockError, match=r"the blocks are: .*commands-not-run"):
        render_page("<!-- figures: no-such-block -->x<!-- /figures -->")
