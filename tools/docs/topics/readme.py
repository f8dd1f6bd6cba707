"""Figure blocks of the readme pages."""

from __future__ import annotations

from tools.docs.blocks import block

__all__ = ["block"]
