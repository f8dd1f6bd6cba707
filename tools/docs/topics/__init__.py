"""The modules that register figure blocks, one per topic of the docs."""

from tools.docs import commands
from tools.docs.topics import api, deployment, models, scenes, speed

__all__ = ["api", "commands", "deployment", "models", "scenes", "speed"]
