"""staging: a change made in `staged_copy` replaces the model directory whole when it
succeeds, and leaves it as it was (no hidden copy left behind) when it fails."""

from pathlib import Path

import pytest

from training.staging import staged_copy


def _model(tmp_path: Path) -> Path:
    model_dir = tmp_path / "arm-pose"
    model_dir.mkdir()
    (model_dir / "manifest.json").write_text("before")
    return model_dir


def test_a_change_that_succeeds_replaces_the_directory(tmp_path: Path) -> None:
    model_dir = _model(tmp_path)
    with staged_copy(model_dir) as staging:
        assert staging.name.startswith(".") and staging != model_dir
        (staging / "manifest.json").write_text("after")
        (staging / "flow_int8.onnx").write_text("new")
        assert (model_dir / "manifest.json").read_text() == "before"  # not yet
    assert (model_dir / "manifest.json").read_text() == "after"
    assert (model_dir / "flow_int8.onnx").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["arm-pose"]


def test_a_change_that_fails_leaves_the_directory_as_it_was(tmp_path: Path) -> None:
    model_dir = _model(tmp_path)
    with pytest.raises(RuntimeError, match="parity"), staged_copy(model_dir) as staging:
        (staging / "manifest.json").write_text("half written")
        raise RuntimeError("parity check failed")
    assert (model_dir / "manifest.json").read_text() == "before"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["arm-pose"]
