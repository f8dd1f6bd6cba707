"""The real app in process: a TestClient over any models directory, and the bundled planar 3R."""

from __future__ import annotations

from pathlib import Path

from fastapi.testclient import TestClient

from service.config import Settings
from service.main import create_app
from service.manifest import REPO_MODELS_DIR

PLANAR3R_DIR = REPO_MODELS_DIR / "planar3r-position"


def make_client(models_dir: Path, **settings: object) -> TestClient:
    return TestClient(create_app(Settings(models_dir=models_dir, **settings)))  # type: ignore[arg-type]
