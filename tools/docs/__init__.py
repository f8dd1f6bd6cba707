"""Figures in the README and the docs, written from the committed reports.

A page marks each generated figure with a pair of HTML comments, which Markdown renders as
nothing on GitHub and in the mkdocs site:

    <!-- figures: models-table -->
    | model | ... |
    <!-- /figures -->

    count right on <!-- figures: report iiwa14-pose count_right -->0.985<!-- /figures -->

The name after `figures:` is a block (the words after it are its arguments); the text
between the markers is what the block writes from the committed reports
(docs/reports/*.json, docs/benchmark/*.json, docs/container.json, models/*/manifest.json),
never a number copied by hand. A block that starts on its own line is written on its own
lines; one inside a sentence stays inline.

    python -m tools.docs           # rewrite every page's figures from the reports
    python -m tools.docs --check   # exit 1, with a diff, if a page differs from that
    python -m tools.docs --examples  # also re-answer the HTTP examples (examples.py)

`tests/docs/test_figures.py` runs the check, so a report re-run without its pages
re-written, or a figure edited by hand, fails the tests.
"""

from tools.docs.blocks import BLOCKS, block
from tools.docs.pages import pages, render_page, rewrite

__all__ = ["BLOCKS", "block", "pages", "render_page", "rewrite"]
