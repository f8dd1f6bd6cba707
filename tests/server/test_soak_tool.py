"""The soak tool (`python -m tools.soak`): its arithmetic, its bad requests, a short run.

- A window's statistics from synthetic outcomes match figures worked out by hand:
  statuses by kind, errors (a transport failure, a 5xx other than 503, a 2xx to a bad
  request, a 4xx to a valid one; never a 503), 5xx other than 503, and p50/p99 (linear
  interpolation between ranks) of the answered single requests and batches separately,
  503s left out.
- The verdicts from synthetic windows: the settle window is the one ending at --settle-s;
  no RSS after it more than 5 % above it (a window at +4.7 % passes, one at +5.3 %
  fails, one at -5.3 % passes: the goals bound growth); the last window's single p99 at
  most 10 % above the settle window's (+9.5 % passes, +10.5 % fails, -20 % passes); a
  run shorter than --settle-s measures neither.
- The speed probe times its work: four times the loop reads more than twice the time.
  The verdicts give its median over the same two spans as the p99 (no goal), and none
  where no window of a span took it, and the p99's ratio over the probe's (no goal).
- Every bad request of the mix gets its documented 4xx from a real server with the
  default settings (docs/bad-inputs.md), and the mix covers every bundled model with
  single requests and batches.
- The requests in a scene come from the committed scenes reports, every model with one
  in turn, and a real server answers each with a 200 that says it checked
  self-collision and as many obstacles as the request holds; a window gives their
  p50/p99 apart from the single requests'.
- Every other batch asks for NDJSON lines: a real server streams them, and the same
  lines without their end line count as a failed request.
- A 20 s soak of 2 clients against that server (--url with --pid) runs end to end: one
  printed line, one RSS reading and one speed probe per 5 s window, single requests,
  requests in a scene, batches and bad requests all answered as they should be, no
  errors, exit code 0, and the JSON record with the command, the commit, the machine,
  the windows and the verdicts.
"""

from __future__ import annotations

import json
import random
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from service.wire import NDJSON
from tests.support.bundled import bundled_model_ids
from tools import soak
from tools.load import request_bodies
from tools.local_server import LocalServer
from tools.soak import (
    Mix,
    Outcome,
    Window,
    format_verdicts,
    format_window,
    main,
    speed_probe_ms,
    verdicts_of,
    whole,
    window_of,
)


def test_window_statistics_from_synthetic_outcomes() -> None:
    outcomes = [Outcome("single", "m", 200, (10 + 10 * i) / 1e3, 1.0) for i in range(11)]
    outcomes += [
        Outcome("single", "m", 503, 0.001, 1.0),  # at capacity: no error, no latency
        Outcome("single", "m", 500, 0.5, 1.0),  # error, 5xx
        Outcome("single", "m", 0, 0.5, 1.0),  # transport failure: error
        Outcome("single", "m", 404, 0.5, 1.0),  # a valid request refused: error
        Outcome("scene", "m", 200, 0.3, 1.0),
        Outcome("scene", "m", 200, 0.5, 1.0),
        Outcome("batch", "m", 200, 1.0, 1.0),
        Outcome("batch", "m", 200, 2.0, 1.0),
        Outcome("batch", "m", 504, 30.0, 1.0),  # error, 5xx
        Outcome("bad", "not-json", 422, 0.002, 1.0),
        Outcome("bad", "unknown-robot", 404, 0.002, 1.0),
        Outcome("bad", "oversized-body", 503, 0.002, 1.0),  # no error
        Outcome("bad", "unknown-field", 200, 0.002, 1.0),  # a bad request answered: error
    ]
    window = window_of(3, 60.0, 90.0, outcomes, rss_bytes=300 * 2**20 + 2**19, probe_ms=2.5)
    assert (window.index, window.start_s, window.end_s) == (3, 60.0, 90.0)
    assert window.rss_mib == 300.5 and window.probe_ms == 2.5
    assert "probe 2.50 ms" in format_window(window)
    assert window.requests == 11 + 4 + 2 + 3 + 4
    assert window.statuses == {
        "single": {"0": 1, "200": 11, "404": 1, "500": 1, "503": 1},
        "scene": {"200": 2},
        "batch": {"200": 2, "504": 1},
        "bad": {"200": 1, "404": 1, "422": 1, "503": 1},
    }
    assert window.errors == 5  # 500, 0, 404 (single); 504; 200 (bad)
    assert window.server_errors == 2  # 500, 504
    # Singles 10, 20, ..., 110 ms: the median is the 6th (60 ms); p99 at rank 0.99 * 10 =
    # 9.9, between 100 and 110 ms: 100 + 0.9 * 10 = 109 ms.
    assert window.single_p50_ms == pytest.approx(60.0)
    assert window.single_p99_ms == pytest.approx(109.0)
    # Batches 1000 and 2000 ms: p50 1500; p99 at rank 0.99: 1000 + 0.99 * 1000 = 1990.
    assert window.batch_p50_ms == pytest.approx(1500.0)
    assert window.batch_p99_ms == pytest.approx(1990.0)
    # Scenes 300 and 500 ms: p50 400; p99 300 + 0.99 * 200 = 498.
    assert window.scene_p50_ms == pytest.approx(400.0)
    assert window.scene_p99_ms == pytest.approx(498.0)


def test_the_speed_probe_times_its_work(monkeypatch: pytest.MonkeyPatch) -> None:
    """Four times the loop reads at least twice the time: the probe times the work, not a
    fixed overhead (the least of its repeats, so a slow run does not move it)."""
    base = speed_probe_ms()
    monkeypatch.setattr(soak, "PROBE_LOOP", 4 * soak.PROBE_LOOP)
    assert speed_probe_ms() > 2 * base > 0


def test_a_window_without_answers_has_no_percentiles() -> None:
    window = window_of(0, 0.0, 60.0, [Outcome("single", "m", 503, 0.001, 1.0)], None)
    assert window.rss_mib is None
    assert (window.single_p50_ms, window.single_p99_ms) == (None, None)
    assert (window.batch_p50_ms, window.batch_p99_ms) == (None, None)
    assert window.errors == 0


def windows(rss_mib: list[float], single_p99_ms: list[float]) -> list[Window]:
    """Windows of 60 s with these RSS and p99 figures; 10 requests each, window 2 with a
    500 and window 3 with a 503."""
    made = []
    for i, (rss, p99) in enumerate(zip(rss_mib, single_p99_ms, strict=True)):
        statuses = {"single": {"200": 10}, "batch": {}, "bad": {}}
        if i == 2:
            statuses["single"] = {"200": 9, "500": 1}
        if i == 3:
            statuses["single"] = {"200": 9, "503": 1}
        made.append(
            Window(
                index=i, start_s=60.0 * i, end_s=60.0 * (i + 1), rss_mib=rss, requests=10,
                statuses=statuses, errors=int(i == 2), server_errors=int(i == 2),
                single_p50_ms=p99 / 2, single_p99_ms=p99, batch_p50_ms=None, batch_p99_ms=None,
                single_latencies_ms=[p99] * 9,
            )
        )  # fmt: skip
    return made


def test_verdicts_compare_the_settle_window_with_what_follows() -> None:
    # Settle at 120 s: window 1 (60 to 120 s), RSS 300 MiB, p99 200 ms. After it the RSS
    # is at most 314 (314 / 300 = 1.0467) and at least 299 (0.9967): within 5 %. The last
    # p99 is 219 ms (219 / 200 = 1.095): within 10 %. The RSS of window 0 does not count.
    verdicts = verdicts_of(windows([250, 300, 310, 314, 299], [900, 200, 230, 260, 219]), 120.0)
    assert verdicts.settle_window == 1
    assert verdicts.rss_at_settle_mib == 300
    assert (verdicts.rss_max_after_mib, verdicts.rss_min_after_mib) == (314, 299)
    assert verdicts.rss_max_ratio == pytest.approx(1.0467)
    assert verdicts.rss_min_ratio == pytest.approx(0.9967)
    assert verdicts.rss_goal_met is True
    assert (verdicts.single_p99_at_settle_ms, verdicts.single_p99_last_ms) == (200, 219)
    assert verdicts.single_p99_ratio == pytest.approx(1.095)
    assert verdicts.p99_goal_met is True
    assert verdicts.requests == 50
    assert verdicts.statuses["single"] == {"200": 48, "500": 1, "503": 1}
    assert (verdicts.errors, verdicts.server_errors, verdicts.server_errors_goal_met) == (
        1, 1, False,
    )  # fmt: skip


def test_verdicts_fail_on_growth_past_the_goals() -> None:
    # 316 / 300 = 1.0533: over 5 % above; 221 / 200 = 1.105: over 10 % above.
    assert verdicts_of(windows([300, 300, 316], [200, 200, 200]), 120.0).rss_goal_met is False
    assert verdicts_of(windows([300, 300, 300], [200, 200, 221]), 120.0).p99_goal_met is False
    # Falls are reported, not failed: 284 / 300 = 0.9467, 160 / 200 = 0.8.
    fallen = verdicts_of(windows([300, 300, 284], [200, 200, 160]), 120.0)
    assert fallen.rss_min_ratio == pytest.approx(0.9467) and fallen.rss_goal_met is True
    assert fallen.single_p99_ratio == pytest.approx(0.8) and fallen.p99_goal_met is True
    # A settle time between window ends takes the first window ending after it.
    assert verdicts_of(windows([300, 400, 410], [200, 200, 200]), 90.0).settle_window == 1


def test_the_p99_goal_is_taken_over_a_span_of_windows() -> None:
    # Windows of 60 s; settle at 180 s (window 2), span 120 s: windows 1 and 2 (latencies
    # 9 x 200 and 9 x 300 ms: the p99 of the 18 lies between the two largest, 300 ms),
    # against windows 4 and 5 (9 x 250 and 9 x 240: 250 ms); window 3's 900 ms is in neither.
    made = windows([300, 300, 300, 300, 300, 300], [100, 200, 300, 900, 250, 240])
    verdicts = verdicts_of(made, 180.0, p99_span_s=120.0)
    assert (verdicts.single_p99_at_settle_ms, verdicts.single_p99_last_ms) == (300, 250)
    assert verdicts.p99_goal_met is True
    # Window 4's p99 raised above 330 ms fails it: 9 x 340 against 300.
    made[4].single_latencies_ms[:] = [340.0] * 9
    assert verdicts_of(made, 180.0, p99_span_s=120.0).p99_goal_met is False
    # One window alone (span 0) compares window 2 with window 5: 240 / 300.
    assert verdicts_of(made, 180.0).single_p99_ratio == pytest.approx(0.8)


def test_the_probe_is_read_over_the_p99_spans() -> None:
    # Settle at 180 s (window 2), span 120 s: windows 1 and 2 (probes 2.0 and 2.2: median
    # 2.1) against windows 4 and 5 (2.4 and 2.6: 2.5); window 3's 9.0 is in neither.
    made = windows([300] * 6, [200] * 6)
    for w, probe in zip(made, [1.0, 2.0, 2.2, 9.0, 2.4, 2.6], strict=True):
        w.probe_ms = probe
    verdicts = verdicts_of(made, 180.0, p99_span_s=120.0)
    assert (verdicts.probe_at_settle_ms, verdicts.probe_last_ms) == (2.1, 2.5)
    assert verdicts.probe_ratio == pytest.approx(2.5 / 2.1, abs=1e-4)
    assert "speed probe (no goal): 2.10 ms at 180 s, 2.50 ms" in format_verdicts(verdicts)
    # Every p99 200 ms (ratio 1) over the probe's 2.5 / 2.1: 0.84.
    assert "the single p99's ratio over it: x0.840" in format_verdicts(verdicts)
    # Windows without a probe (a record from before it) give none.
    untaken = verdicts_of(windows([300] * 6, [200] * 6), 180.0, p99_span_s=120.0)
    assert (untaken.probe_at_settle_ms, untaken.probe_last_ms, untaken.probe_ratio) == (
        None, None, None,
    )  # fmt: skip


def test_a_run_shorter_than_the_settle_time_measures_no_goal() -> None:
    verdicts = verdicts_of(windows([300, 300], [200, 200]), 300.0)
    assert verdicts.settle_window is None
    assert (verdicts.rss_goal_met, verdicts.p99_goal_met) == (None, None)
    # Nothing after the settle window: nothing to compare either.
    verdicts = verdicts_of(windows([300, 300], [200, 200]), 120.0)
    assert verdicts.settle_window == 1
    assert (verdicts.rss_goal_met, verdicts.p99_goal_met) == (None, None)


@pytest.fixture(scope="module")
def server() -> Iterator[LocalServer]:
    with LocalServer(log_level="warning") as running:  # the default limits
        yield running


def test_every_bad_request_of_the_mix_gets_its_4xx(server: LocalServer) -> None:
    mix = Mix.of(request_bodies(seed=0), batch_targets=4)
    assert sorted(mix.singles) == sorted(mix.batches) == bundled_model_ids()
    assert all(mix.singles.values()) and all(mix.batches.values())
    answered = {}
    with httpx.Client(base_url=server.url, timeout=30) as client:
        for call in mix.bad:
            headers = {"content-type": call.content_type} if call.content_type else {}
            response = client.post(call.path, content=call.content, headers=headers)
            answered[call.name] = response.status_code
    print(answered)
    assert answered == {call.name: call.expected_status for call in mix.bad}
    assert all(400 <= status < 500 for status in answered.values())
    # A cycle: one single request per model, one in a scene, one batch, two bad requests.
    cycle = mix.cycle(0, random.Random(0))
    kinds = ["single"] * len(mix.singles) + ["scene", "batch"] + ["bad"] * 2
    assert [call.kind for call in cycle] == kinds
    assert cycle[-2:] == mix.bad[:2] and mix.cycle(1, random.Random(0))[-2:] == mix.bad[2:4]


def test_the_requests_in_a_scene_are_answered_with_their_obstacles(server: LocalServer) -> None:
    scenes = soak.scene_calls()
    reports = sorted(soak.SCENES_DIR.glob("*.json"))
    assert len(reports) >= 2 and len(scenes) == soak.SCENES_PER_MODEL * len(reports)
    models = [call.name for call in scenes[: len(reports)]]
    assert len(set(models)) == len(reports)  # every model in turn
    assert {name.split("@")[0] for name in models} <= set(bundled_model_ids())
    mix = Mix.of(request_bodies(seed=0), batch_targets=2)
    assert [mix.cycle(i, random.Random(0))[len(mix.singles)] for i in range(3)] == scenes[:3]
    with httpx.Client(base_url=server.url, timeout=60) as client:
        for call in scenes[: len(reports)]:
            response = client.post(call.path, content=call.content, headers=call.headers)
            assert response.status_code == 200, response.text
            asked = json.loads(call.content)
            collision = response.json()["collision"]
            assert collision["self_checked"] is True
            assert collision["obstacles"] == len(asked["obstacles"]) > 0


def test_half_the_batches_ask_for_lines_and_a_cut_stream_is_a_failure(
    server: LocalServer,
) -> None:
    mix = Mix.of(request_bodies(seed=0), batch_targets=2)
    for batches in mix.batches.values():
        assert [call.accept for call in batches[:2]] == [None, NDJSON]
    call = next(iter(mix.batches.values()))[1]
    with httpx.Client(base_url=server.url, timeout=60) as client:
        response = client.post(call.path, content=call.content, headers=call.headers)
    assert response.headers["content-type"] == NDJSON
    assert whole(call, 200, response.content) == 200
    cut = response.content.rsplit(b"\n", 2)[0] + b"\n"  # without the end line
    assert whole(call, 200, cut) == 0
    assert whole(call, 503, b"") == 503


def test_a_short_soak_runs_end_to_end(
    server: LocalServer, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    record_path = tmp_path / "soak.json"
    code = main(
        [
            "--url", server.url, "--pid", str(server.pid), "--clients", "2",
            "--duration-s", "20", "--interval-s", "5", "--settle-s", "5",
            "--json", str(record_path),
        ]
    )  # fmt: skip
    printed = capsys.readouterr().out
    print(printed)
    assert code == 0
    record = json.loads(record_path.read_text())
    assert record["command"].startswith("python -m tools.soak --url")
    assert record["git_commit"]
    assert record["machine"]["cores"] >= 1
    assert isinstance(record["server_environment"], dict)  # MALLOC_ARENA_MAX and the like
    assert [w["end_s"] for w in record["windows"]] == [5.0, 10.0, 15.0, 20.0]
    assert sum(" s  RSS " in line for line in printed.splitlines()) == 4
    assert all(w["rss_mib"] > 0 and w["probe_ms"] > 0 for w in record["windows"])
    verdicts = record["verdicts"]
    assert verdicts["errors"] == 0 and verdicts["server_errors_goal_met"] is True
    assert verdicts["settle_window"] == 0 and verdicts["rss_goal_met"] is not None
    assert set(verdicts["statuses"]["single"]) <= {"200", "503"}
    assert set(verdicts["statuses"]["batch"]) <= {"200", "503"}
    assert set(verdicts["statuses"]["scene"]) <= {"200", "503"}
    assert verdicts["statuses"]["single"]["200"] > 0 and verdicts["statuses"]["batch"]["200"] > 0
    assert verdicts["statuses"]["scene"]["200"] > 0
    assert all(400 <= int(status) < 500 for status in verdicts["statuses"]["bad"])
