"""The int8 exactness measurement (`python -m tools.int8_exactness`): onnxruntime's velocities
equal the exact network's (the compiled layers') on every row where the processor gives
onnxruntime an exact product (VNNI or AMX), and differ on rows of a sampler's call where
it does not; the figures are finite and the share a share."""

from __future__ import annotations

import math

from service.manifest import FLOW_INT8_FILE, REPO_MODELS_DIR
from tools.int8_exactness import int8_networks, measure, onnxruntime_product_exact


def test_onnxruntime_differs_from_the_exact_network_only_without_vnni_or_amx() -> None:
    result = measure(REPO_MODELS_DIR / "planar3r-position" / FLOW_INT8_FILE, rows=200, seed=0)
    assert result["rows"] == 800  # 200 rows at each of the four t
    assert math.isfinite(float(result["largest_velocity"]))  # type: ignore[arg-type]
    share = float(result["rows_differing_share"])  # type: ignore[arg-type]
    assert 0.0 <= share <= 1.0
    if onnxruntime_product_exact():
        assert result["largest_difference"] == 0.0 and share == 0.0
    else:
        assert share > 0.0


def test_every_bundled_int8_network_is_measured() -> None:
    paths = int8_networks()
    assert {p.parent.name for p in paths} == {
        p.parent.name for p in REPO_MODELS_DIR.glob(f"*/{FLOW_INT8_FILE}")
    }
    assert all(p.name.endswith("_int8.onnx") and p.is_file() for p in paths)
