"""training.evaluate.scenes.report: the whole section on two Panda pose targets, and on a
UR5 tool-axis target.

Every configuration the service returned or called free is free by coal (0 violations,
by coal's own distances too: the least clearance of the returned ones is above 0), the
answers are `run`'s, each target's request replays as a POST /smm body the API accepts,
the figures over the targets are the sums of the per-target ones, the JSON as written
(one line per target) reads back as the report, and the page renders from it. An axis
target's request carries the tool axis its configuration reaches (the axis the model's
kinematics gives, to 1e-12), replays to the same answer, and its page says why it has no
free-piece recall.
"""

from __future__ import annotations

import json
from dataclasses import asdict

import numpy as np

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.collision.scene import Obstacle
from service.pipeline.run import run
from service.pipeline.types import Query
from service.wire import SmmRequest
from training.evaluate.scenes.coal_model import CoalModel
from training.evaluate.scenes.rendering import markdown
from training.evaluate.scenes.report import build_scenes_report, report_json


def test_two_panda_targets_have_no_violation(
    panda_pose_model: ServedModel, panda_coal: CoalModel
) -> None:
    built = build_scenes_report(panda_pose_model, 2, seed=11, max_obstacles=4, margin_m=0.0)
    written = report_json(built)
    report = json.loads(written)
    assert report == json.loads(json.dumps(built))
    assert len(written.splitlines()[-4]) > 1000  # the last target on one line
    summary, targets = report["summary"], report["per_target"]
    exactness = summary["exactness"]
    assert exactness["returned"]["violations"] == exactness["recorded"]["violations"] == 0
    assert exactness["returned"]["checked"] > 0 and exactness["answers_differing_from_run"] == []
    for target in targets:
        body = SmmRequest.model_validate(target["request"])
        assert len(body.obstacles) == len(target["request"]["obstacles"]) >= 1
        boxes = [
            Obstacle.of(i, o["shape"], o["dimensions"], o["position"],
                        tuple(o["orientation"][k] for k in "wxyz"))
            for i, o in enumerate(target["request"]["obstacles"])
        ]  # fmt: skip
        q = np.asarray(target["q_target_rad"])[None]
        assert panda_coal.clearance_m(q, boxes)[0] > 0
        sent = target["request"]
        replayed = run(
            panda_pose_model,
            Query.for_model(
                panda_pose_model.manifest, position_m=sent["target"]["position"],
                orientation_wxyz=tuple(sent["target"]["orientation"][k] for k in "wxyz"),
                num_samples=sent["num_samples"], seed=sent["seed"], obstacles=boxes,
            ),
        )  # fmt: skip
        assert len(replayed.components) == target["components"]
        assert asdict(replayed.counts) == target["counts"]
        assert set(target["time_ms"]) == {"scene", "self_only", "nothing_checked", "10_boxes"}
    recall = summary["recall"]
    assert recall["pieces_asked"] == sum(t["recall"]["asked"] for t in targets) > 0
    assert recall["merges"] == sum(t["recall"]["merges"] for t in targets)
    lost = sum(t["free_space"]["lost"] for t in targets)
    assert summary["free_space"]["lost_points"] == lost
    page = markdown("panda-pose", report)
    assert page.startswith("# Scenes: panda-pose") and "| exactly 10 boxes |" in page


def test_an_axis_target_is_asked_with_the_axis_it_reaches() -> None:
    model = load_model(REPO_MODELS_DIR / "ur5-axis", threads=0)
    tool_axis = model.manifest.task.tool_axis
    assert tool_axis is not None
    report = json.loads(report_json(build_scenes_report(model, 1, 5, 3, 0.0)))
    assert report["task"] == "axis" and report["summary"]["recall"] is None
    exactness = report["summary"]["exactness"]
    assert exactness["returned"]["violations"] == exactness["recorded"]["violations"] == 0
    (target,) = report["per_target"]
    sent = target["request"]
    body = SmmRequest.model_validate(sent)
    fk = model.kinematics(np.asarray(target["q_target_rad"])[None])
    np.testing.assert_allclose(sent["target"]["axis"], fk.rotation[0] @ tool_axis, atol=1e-12)
    assert "orientation" not in sent["target"] and body.target.axis is not None
    x, y, z = body.target.axis
    boxes = [
        Obstacle.of(i, o["shape"], o["dimensions"], o["position"],
                    tuple(o["orientation"][k] for k in "wxyz"))
        for i, o in enumerate(sent["obstacles"])
    ]  # fmt: skip
    replayed = run(
        model,
        Query.for_model(
            model.manifest, position_m=sent["target"]["position"], axis=(x, y, z),
            num_samples=sent["num_samples"], seed=sent["seed"], obstacles=boxes,
        ),
    )  # fmt: skip
    assert len(replayed.components) == target["components"]
    assert asdict(replayed.counts) == target["counts"]
    assert target["free_space"]["coal_free"] > 0
    assert "Not measured for the tool-axis task" in markdown("ur5-axis", report)
