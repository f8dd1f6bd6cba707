"""The registry of figure blocks: a name -> a function of the block's arguments that
returns the Markdown the committed reports give for it."""

from __future__ import annotations

from collections.abc import Callable

Block = Callable[..., str]
BLOCKS: dict[str, Block] = {}


class UnknownBlockError(LookupError):
    """A page names a block that no module registers."""


def block(name: str) -> Callable[[Block], Block]:
    """Register `function` as the block `name` (lower case, digits and hyphens)."""

    def register(function: Block) -> Block:
        if name in BLOCKS:
            raise ValueError(f"figure block {name!r} is registered twice")
        BLOCKS[name] = function
        return function

    return register


def run_block(name: str, arguments: list[str]) -> str:
    """The text of block `name` with `arguments`; an unknown name lists the valid ones."""
    load_topics()
    if name not in BLOCKS:
        raise UnknownBlockError(
            f"unknown figure block {name!r}; the blocks are: {', '.join(sorted(BLOCKS))}"
        )
    return BLOCKS[name](*arguments)


def load_topics() -> None:
    """Import every module that registers blocks (each registers on import)."""
    from tools.docs import topics  # noqa: F401  (imported for its registrations)
