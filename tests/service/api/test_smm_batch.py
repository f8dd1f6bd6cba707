"""POST /smm/batch over HTTP: each target's answer is POST /smm's for the same target,
options and seed (JSON equal, timings aside; planar 3R and iiwa14 pose), in order, with
its status; a target's option replaces the batch's; every bad target is named by its
index in one 422 (a batch option once, at the batch); 413 over the targets, per-target
and total sample limits, 404 for an unknown model, 422 for an empty list; a batch the
deadline cut short says so per target; the route is in the OpenAPI document."""

from __future__ import annotations

import asyncio
import time
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.api.answers import encode
from service.api.batch_lines import BatchLines, first_line_or_error
from service.api.smm import smm_fields
from service.api.smm_batch import answer_lines, batch_fields
from service.errors import DeadlineExceededError
from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel
from service.observability.metrics import Metrics
from service.pipeline.batch import BatchResult, run_batch
from service.pipeline.deadline import Deadline
from service.pipeline.run import run
from service.pipeline.types import Query
from service.wire import (
    NDJSON,
    BatchItemOut,
    SmmBatchEnd,
    SmmBatchHead,
    SmmBatchResponse,
    SmmResponse,
)
from tests.support.app import make_client
from tests.support.bundled import bundled_robots, served_robots_message
from tests.support.metrics import metric
from tests.support.watched import condition_of, slow_on, watched

PLANAR = {"robot": "planar3r", "task": "position"}
POSE_TARGETS: list[dict[str, Any]] = [
    {
        "position": [0.6501, 0.2011, 0.5018],
        "orientation": {"w": 0.2165, "x": -0.1458, "y": 0.9648, "z": 0.0327},
    },
    {"position": [0.5, 0.1, 0.6], "orientation": {"w": 0.0, "x": 1.0, "y": 0.0, "z": 0.0}},
]
ERRORS = {"200", "400", "401", "404", "413", "415", "422", "503", "504"}


def batch(client: TestClient, targets: list[dict[str, Any]], **options: Any) -> Any:
    return client.post("/smm/batch", json={**PLANAR, **options, "targets": targets})


def without_timings(answer: dict[str, Any]) -> dict[str, Any]:
    return {key: value for key, value in answer.items() if key != "timings_ms"}


def single(client: TestClient, body: dict[str, Any]) -> dict[str, Any]:
    response = client.post("/smm", json=body)
    assert response.status_code == 200, response.text
    return without_timings(response.json())


def test_each_answer_is_the_single_answer_with_the_batch_options_or_its_own(
    client: TestClient,
) -> None:
    targets: list[dict[str, Any]] = [
        {"target": {"position": [0.5, 0.0]}},
        {"target": {"position": [0.5, 0.2]}, "seed": 11},
        {"target": {"position": [3.5, 0.0]}},
        {
            "target": {"position": [0.3, -0.6]},
            "num_samples": 150,
            "reference_configuration": [0.1, 1.9, 2.6],
            "tolerance": {"position": 1e-8},
            "max_configurations_per_component": 5,
            "include_paths": False,
        },
    ]
    options = {"num_samples": 200, "seed": 4, "max_configurations_per_component": 20}
    response = batch(client, targets, **options)
    assert response.status_code == 200, response.text
    answer = response.json()
    assert answer["status"] == "complete"
    assert answer["model"].startswith("planar3r-position@")
    assert [r["index"] for r in answer["results"]] == [0, 1, 2, 3]
    assert [r["status"] for r in answer["results"]] == ["ok", "ok", "no_solution", "ok"]
    singles = [
        {**PLANAR, **options, "target": {"position": [0.5, 0.0]}},
        {**PLANAR, **options, "target": {"position": [0.5, 0.2]}, "seed": 11},
        {**PLANAR, **options, "target": {"position": [3.5, 0.0]}},
        {**PLANAR, **options, **targets[3]},
    ]
    for result, body in zip(answer["results"], singles, strict=True):
        assert without_timings(result["answer"]) == single(client, body)
    # The batch's options reached every target that gave none, the target's own the other.
    assert [r["answer"]["counts"]["sampled"] for r in answer["results"]] == [200, 200, 200, 150]
    assert answer["results"][3]["answer"]["components"][0]["path"] is None
    assert answer["results"][0]["answer"]["components"][0]["path"]
    assert set(answer["timings_ms"]) == {
        "encode", "sample", "correct", "accept", "connect", "summarise", "total",
    }  # fmt: skip


def test_the_same_target_with_another_seed_is_another_answer(client: TestClient) -> None:
    """The equality above can fail: the seed reaches each target."""
    targets = [{"target": {"position": [0.5, 0.0]}, "seed": s} for s in (1, 2)]
    first, second = batch(client, targets, num_samples=100).json()["results"]
    assert first["answer"]["components"] != second["answer"]["components"]


def test_iiwa14_pose_answers_are_the_single_answers(client: TestClient) -> None:
    pose = {"robot": "iiwa14", "task": "pose", "num_samples": 60}
    response = client.post(
        "/smm/batch",
        json={**pose, "targets": [{"target": t, "seed": i} for i, t in enumerate(POSE_TARGETS)]},
    )
    assert response.status_code == 200, response.text
    results = response.json()["results"]
    for i, (result, target) in enumerate(zip(results, POSE_TARGETS, strict=True)):
        assert result["status"] == "ok"
        assert without_timings(result["answer"]) == single(
            client, {**pose, "target": target, "seed": i}
        )


def locations_and_messages(response: Any) -> list[tuple[list[Any], str]]:
    return [(error["loc"], error["msg"]) for error in response.json()["detail"]]


def test_every_bad_target_is_named_by_its_index_in_one_422(client: TestClient) -> None:
    pose_targets = [
        {"target": POSE_TARGETS[0]},
        {"target": {"position": [0.5, 0.1, 0.6]}},  # no orientation
        {"target": POSE_TARGETS[1]},
        {"target": {**POSE_TARGETS[1], "orientation": {"w": 0, "x": 2, "y": 0, "z": 0}}},
        {"target": {"position": [0.5, 0.1]}},
        {"target": POSE_TARGETS[0], "reference_configuration": [0.0, 0.1]},
    ]
    response = client.post(
        "/smm/batch", json={"robot": "iiwa14", "task": "pose", "targets": pose_targets}
    )
    assert response.status_code == 422
    assert locations_and_messages(response) == [
        (
            ["body", "targets", 1, "target", "orientation"],
            "targets[1].target.orientation (a unit quaternion {w, x, y, z}) is required for "
            "the pose task",
        ),
        (
            ["body", "targets", 3, "target", "orientation"],
            "targets[3].target.orientation must be a unit quaternion (norm within 0.01 of 1, "
            "normalised then), got norm 2",
        ),
        (
            ["body", "targets", 4, "target", "position"],
            "targets[4].target.position must have 3 values (x, y, z) for the pose task of this "
            "robot, got 2",
        ),
        (
            ["body", "targets", 5, "reference_configuration"],
            "targets[5].reference_configuration must have 7 values (one per joint), got 2",
        ),
    ]


def test_malformed_targets_are_all_named_by_their_index(client: TestClient) -> None:
    targets: list[dict[str, Any]] = [
        {"target": {"position": [0.5, 0.0]}},
        {"target": {"position": [0.5, "a"]}},
        {"target": {"position": [0.5, 0.0]}, "num_samples": 0},
        {"target": {"position": [0.5, 0.0]}, "sed": 3},
        {"position": [0.5, 0.0]},
    ]
    response = batch(client, targets)
    assert response.status_code == 422
    found = locations_and_messages(response)
    assert [location for location, _ in found] == [
        ["body", "targets", 1, "target", "position", 1],
        ["body", "targets", 2, "num_samples"],
        ["body", "targets", 3, "sed"],
        ["body", "targets", 4, "target"],
        ["body", "targets", 4, "position"],
    ]
    messages = [message for _, message in found]
    assert messages[0].startswith("targets[1].target.position[1]: Input should be a valid number")
    assert messages[1] == (
        "targets[2].num_samples: Input should be greater than or equal to 1; allowed: an "
        "integer >= 1 and <= 5000 (this server's limit), or null / omitted"
    )
    assert messages[2].startswith("targets[3].sed: unknown field 'sed'")
    assert "only the fields target, num_samples, seed, tolerance" in messages[2]


def test_a_bad_batch_option_is_named_once_at_the_batch(client: TestClient) -> None:
    targets: list[dict[str, Any]] = [
        {"target": {"position": [0.5, 0.0]}},
        {"target": {"position": [0.5, 0.1]}, "reference_configuration": [0.0, 0.0]},
        {"target": {"position": [0.5, 0.2]}},
    ]
    response = batch(client, targets, reference_configuration=[0.0, 0.0, 0.0, 0.0])
    assert response.status_code == 422
    assert locations_and_messages(response) == [
        (
            ["body", "reference_configuration"],
            "reference_configuration must have 3 values (one per joint), got 4",
        ),
        (
            ["body", "targets", 1, "reference_configuration"],
            "targets[1].reference_configuration must have 3 values (one per joint), got 2",
        ),
    ]


def test_an_empty_list_of_targets_is_refused(client: TestClient) -> None:
    response = batch(client, [])
    assert response.status_code == 422
    ((location, message),) = locations_and_messages(response)
    assert location == ["body", "targets"]
    assert message.startswith("targets: List should have at least 1 item")


def test_over_the_limits_is_413(client: TestClient) -> None:
    one = {"target": {"position": [0.5, 0.0]}}
    response = batch(client, [one] * 65, num_samples=10)
    assert response.status_code == 413
    assert response.json()["detail"] == (
        "targets must hold at most 64 targets on this server (SMM_MAX_BATCH_TARGETS), got 65"
    )
    response = batch(client, [one, {**one, "num_samples": 5001}])
    assert response.status_code == 413
    assert response.json()["detail"] == (
        "targets[1].num_samples must be at most 5000 on this server, got 5001"
    )
    response = batch(client, [one], num_samples=5001)
    assert response.status_code == 413
    assert response.json()["detail"] == "num_samples must be at most 5000 on this server, got 5001"
    response = batch(client, [one] * 13, num_samples=5000)
    assert response.status_code == 413
    assert response.json()["detail"] == (
        "the targets' num_samples must add up to at most 64000 on this server "
        "(SMM_MAX_BATCH_SAMPLES), got 65000"
    )


def test_an_unknown_robot_or_task_is_404_listing_what_is_served(client: TestClient) -> None:
    targets = [{"target": {"position": [0.5, 0.0]}}]
    response = client.post("/smm/batch", json={"robot": "ur10", "task": "pose", "targets": targets})
    assert response.status_code == 404
    assert response.json()["detail"] == f"unknown robot 'ur10'; {served_robots_message()}"
    response = batch(client, targets, task="pose")
    assert response.status_code == 404
    assert response.json()["detail"] == (
        "unknown task 'pose' for robot 'planar3r'; served tasks: position"
    )


def test_a_batch_cut_by_the_deadline_marks_the_targets_left(planar3r: ServedModel) -> None:
    queries = [
        Query.for_model(planar3r.manifest, position_m=[0.5, y], num_samples=50) for y in (0, 0.1)
    ]
    answered = run_batch(planar3r, queries[:1])
    expired = Deadline(budget_s=1.0, expires_at_s=0.0)
    stopped = run_batch(planar3r, queries[1:], expired).deadline_error
    cut = BatchResult(answered.results, stopped, answered.total_ms)
    response = SmmBatchResponse.model_validate_json(encode(batch_fields(planar3r, queries, cut)))
    assert response.status == "partial"
    assert [(r.index, r.status) for r in response.results] == [(0, "ok"), (1, "deadline_exceeded")]
    assert response.results[1].answer is None


LINES = {"Accept": NDJSON}


def lines_of(response: Any) -> SmmBatchResponse:
    """The answer an NDJSON response's lines make up (head, one item per target, end)."""
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == NDJSON
    lines = response.text.splitlines()
    items = [BatchItemOut.model_validate_json(line) for line in lines[1:-1]]
    head = SmmBatchHead.model_validate_json(lines[0])
    return SmmBatchResponse.of_lines(head, items, SmmBatchEnd.model_validate_json(lines[-1]))


def answers_without_timings(answer: SmmBatchResponse) -> dict[str, Any]:
    fields = answer.model_dump(mode="json")
    for result in fields["results"]:
        result["answer"] = result["answer"] and without_timings(result["answer"])
    return without_timings(fields)


@pytest.mark.parametrize("robot", ["planar3r", "iiwa14"])
def test_the_lines_make_up_the_json_answer(client: TestClient, robot: str) -> None:
    if robot == "planar3r":
        body: dict[str, Any] = {
            **PLANAR,
            "num_samples": 150,
            "max_configurations_per_component": 4,
            "targets": [
                {"target": {"position": [0.5, 0.0]}},
                {"target": {"position": [3.5, 0.0]}},  # out of reach
                {"target": {"position": [0.5, 0.2]}, "seed": 9, "include_paths": False},
            ],
        }
    else:
        targets = [{"target": t, "seed": i} for i, t in enumerate(POSE_TARGETS)]
        body = {"robot": "iiwa14", "task": "pose", "num_samples": 60, "targets": targets}
    whole = SmmBatchResponse.model_validate_json(client.post("/smm/batch", json=body).content)
    streamed = lines_of(client.post("/smm/batch", json=body, headers=LINES))
    assert answers_without_timings(streamed) == answers_without_timings(whole)
    assert [r.index for r in streamed.results] == list(range(len(body["targets"])))
    assert streamed.status == "complete" and set(streamed.timings_ms) == set(whole.timings_ms)
    if robot == "planar3r":
        assert [r.status for r in streamed.results] == ["ok", "no_solution", "ok"]


class Lines:
    """`answer_lines` run in a worker thread as the route runs it, its lines read back
    (`first`: only so many, then the reader leaves), its metrics kept."""

    def __init__(
        self, model: ServedModel, queries: list[Query], deadline: Deadline, threads: int = 2
    ) -> None:
        self.model, self.queries, self.deadline, self.threads = model, queries, deadline, threads
        self.metrics = Metrics()

    async def read(self, first: int | None = None) -> list[bytes]:
        lines = BatchLines()
        computation = asyncio.ensure_future(
            asyncio.to_thread(
                answer_lines, self.model, self.queries, self.deadline, self.threads, lines,
                self.metrics,
            )
        )  # fmt: skip
        await first_line_or_error(lines, computation)
        read: list[bytes] = []
        reader = lines.read(computation)
        async for line in reader:
            read.append(line)
            if first is not None and len(read) == first:
                await reader.aclose()  # the client leaves
                await computation  # the worker stops: the targets under way finish
                break
        return read

    def answers_observed(self) -> float:
        """How many answers the metrics saw computed (each observes its total time once)."""
        text = self.metrics.exposition(None)[0].decode()
        labels = {"model": self.model.manifest.model_id, "stage": "total"}
        return metric(text, "smm_pipeline_stage_duration_seconds_count", **labels)


def test_every_answer_computed_is_counted_when_the_client_leaves(planar3r: ServedModel) -> None:
    queries = [
        Query.for_model(planar3r.manifest, position_m=[0.5, 0.01 * i], num_samples=50, seed=i)
        for i in range(6)
    ]
    first = condition_of(planar3r, queries[0].position_m)
    sampled: set[bytes] = set()  # the conditions of the targets whose sampling began

    def watch(condition: np.ndarray) -> None:
        sampled.add(condition.tobytes())
        if condition.tobytes() != first:
            time.sleep(0.3)  # the other worker's target is under way when the client leaves

    streamed = Lines(watched(planar3r, watch), queries, Deadline.after(60.0), threads=2)
    lines = asyncio.run(streamed.read(first=2))  # the head and the first answer
    assert len(lines) == 2
    # Every target begun was answered and counted, the ones never sent too; the rest
    # were never started.
    assert 2 <= len(sampled) < len(queries)
    assert streamed.answers_observed() == len(sampled)
    whole = Lines(planar3r, queries, Deadline.after(60.0))
    asyncio.run(whole.read())
    assert whole.answers_observed() == len(queries)


def test_a_deadline_mid_batch_sends_the_targets_left_as_deadline_exceeded(
    planar3r: ServedModel,
) -> None:
    queries = [
        Query.for_model(planar3r.manifest, position_m=[0.5, y], num_samples=50, seed=1)
        for y in (0.0, 0.2, 0.4)
    ]
    deadline = Deadline.after(2.0)
    slow = slow_on(planar3r, [0.5, 0.2], deadline)
    lines = asyncio.run(Lines(slow, queries, deadline).read())
    assert len(lines) == 5 and all(line.endswith(b"\n") for line in lines)
    head = SmmBatchHead.model_validate_json(lines[0])
    items = [BatchItemOut.model_validate_json(line) for line in lines[1:4]]
    end = SmmBatchEnd.model_validate_json(lines[4])
    assert [(i.index, i.status) for i in items] == [
        (0, "ok"), (1, "deadline_exceeded"), (2, "deadline_exceeded"),
    ]  # fmt: skip
    assert end.status == "partial" and head.model.startswith("planar3r-position@")
    alone = Query.for_model(planar3r.manifest, position_m=[0.5, 0.0], num_samples=50, seed=1)
    single = SmmResponse.model_validate_json(
        encode(smm_fields(planar3r, alone, run(planar3r, alone)))
    )
    assert items[0].answer is not None
    assert without_timings(items[0].answer.model_dump()) == without_timings(single.model_dump())


def test_a_deadline_before_the_first_answer_raises_before_any_line(planar3r: ServedModel) -> None:
    queries = [Query.for_model(planar3r.manifest, position_m=[0.5, 0.0], num_samples=50)]
    expired = Deadline(budget_s=1.0, expires_at_s=0.0)
    with pytest.raises(DeadlineExceededError):  # the route's 504, as the JSON answer's
        asyncio.run(Lines(planar3r, queries, expired).read())


def test_the_route_is_documented(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    operation = spec["paths"]["/smm/batch"]["post"]
    assert set(operation["responses"]) == ERRORS
    assert "SMM_MAX_BATCH_TARGETS" in operation["responses"]["413"]["description"]
    request = spec["components"]["schemas"]["SmmBatchRequest"]["properties"]
    assert request["robot"]["enum"] == bundled_robots()
    assert request["targets"]["minItems"] == 1
    result = spec["components"]["schemas"]["BatchItemOut"]["properties"]
    assert result["status"]["enum"] == ["ok", "no_solution", "deadline_exceeded"]
    assert set(operation["responses"]["200"]["content"]) == {"application/json", NDJSON}
    assert "application/x-ndjson" in operation["responses"]["200"]["description"]


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_the_batch_threads_setting_leaves_answers_unchanged(threads: int) -> None:
    targets = [{"target": {"position": [0.5, y]}} for y in (0.0, 0.3, 0.6)]
    with make_client(REPO_MODELS_DIR, batch_threads=threads) as other:
        theirs = batch(other, targets, num_samples=100).json()["results"]
    with make_client(REPO_MODELS_DIR) as default:
        ours = batch(default, targets, num_samples=100).json()["results"]
    assert [without_timings(r["answer"]) for r in theirs] == [
        without_timings(r["answer"]) for r in ours
    ]
