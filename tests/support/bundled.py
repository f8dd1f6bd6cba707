"""The bundled models as their manifest files list them, read as JSON (not through the
registry the tests check), so tests that name what is served follow models/."""

from __future__ import annotations

import json

from service.manifest import MANIFEST_FILE, REPO_MODELS_DIR


def bundled_model_ids() -> list[str]:
    paths = sorted(REPO_MODELS_DIR.glob(f"*/{MANIFEST_FILE}"))
    return sorted(json.loads(p.read_text())["model_id"] for p in paths)


def bundled_robots() -> list[str]:
    paths = sorted(REPO_MODELS_DIR.glob(f"*/{MANIFEST_FILE}"))
    return sorted({json.loads(p.read_text())["robot"] for p in paths})


def served_robots_message() -> str:
    """The tail of the 404 for an unknown robot."""
    return "served robots: " + ", ".join(bundled_robots())


def default_num_samples(model_id: str) -> int:
    """The samples a request without num_samples gets from the bundled model (its sweep's
    choice)."""
    manifest = json.loads((REPO_MODELS_DIR / model_id / MANIFEST_FILE).read_text())
    return int(manifest["defaults"]["num_samples"])
