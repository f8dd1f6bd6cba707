"""Service settings: one pydantic-settings class, each field from an `SMM_` environment variable."""

from __future__ import annotations

from pathlib import Path

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

REPO_MODELS_DIR = Path(__file__).resolve().parent.parent / "models"


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="SMM_", extra="forbid")

    models_dir: Path = Field(REPO_MODELS_DIR, description="Directory of <model-id>/ folders.")
    host: str = Field("127.0.0.1", description="Interface uvicorn binds to.")
    port: int = Field(8000, ge=1, le=65535)
    max_num_samples: int = Field(
        10_000, ge=1, description="Largest num_samples a request may ask for (413 beyond)."
    )
    onnx_threads: int = Field(
        0, ge=0, description="onnxruntime intra-op threads per session; 0 uses every core."
    )
    log_level: str = Field("info", description="uvicorn log level.")
