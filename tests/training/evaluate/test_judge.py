"""judge: serving defaults judged against the exact SMMs, and the export's use of it.

- The judge's figures pool every target's draws, each draw's answer measured as the
  evaluation measures it; a candidate is worse where a figure's paired test over the
  targets (paired.py) or the coverage margin says so, each reason naming its figure.
- The near-singular targets of the planar 3R lie near its critical values, rho = 1 and
  rho = 3 of the unit-link arm (the closed form), where few uniform targets do.
- A candidate that returns one sample misses the second loop inside rho = 1 and is judged
  worse on count right; the incumbent judged against itself is no worse.
- With a candidate seed offset, the candidate's figures are the evaluation's figures of
  its answers drawn from seeds i + offset (+ the draw's stride), computed here without the
  judge, and its paired gains those of its per-target sums; the incumbent
  against itself so is judged on other draws (the verdict says so); the CLI records the
  offset and refuses to `--write` such a judgement, naming the option.
- `judged_defaults`: swept defaults equal to the incumbent's serve without a judgement;
  worse ones give way to the incumbent's, its reasons kept, the verdict with its figures
  in reasons, and the sweep's reason for an axis the incumbent had none for marked unserved;
  a robot without an exact reference keeps the swept ones, saying they were not judged.
- The CLI judges the paper's configuration (100 float32 Euler steps, 3 DLS, the rest
  served) or a JSON change of the served defaults; anything else is refused, naming both
  forms; its JSON record holds both defaults, both sets of figures and the verdict.
- A candidate network (another trained model of the same robot and task) is judged at
  its own defaults, or at the served ones changed by `--candidate`, against the served
  network: the served network itself is no worse,
  with equal figures; a network whose velocity drives every sample to one point is worse
  on count right; a model of another robot is refused, naming the field; with `--write`
  the CLI puts a candidate judged no worse in the model's place (its files, the verdict
  in its reasons) and leaves the model as it was for one judged worse.
- A candidate judged no worse serves with the verdict in its reasons and each reason of a
  field it changed marked as set by it; one judged worse cannot. `--write` writes only a
  candidate judged no worse, into the manifest of the model it judged.
"""

import json
import shutil
from dataclasses import replace
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from service.manifest import MANIFEST_FILE, REPO_MODELS_DIR, Manifest
from service.models.registry import ServedModel
from training.cli import main as smm_train
from training.evaluate import judge as judging
from training.evaluate.methods import served_target
from training.evaluate.references.planar3r import planar3r_position
from training.evaluate.served import serving
from training.evaluate.targets import uniform_configurations
from training.evaluate.truth import ground_truth

SMALL = partial(judging.judge, targets=12, near_singular=4)


def _critical_gap(q_rad: np.ndarray) -> np.ndarray:  # (T,) distance of rho to {1, 3}
    rho = np.linalg.norm(planar3r_position(q_rad), axis=-1)
    return np.minimum(np.abs(rho - 1.0), np.abs(rho - 3.0))


def test_near_singular_planar_targets_lie_near_its_critical_values(planar3r: ServedModel) -> None:
    q = judging.near_singular_configurations(planar3r, count=10, seed=3)
    assert q.shape == (10, 3)
    limits = planar3r.limits
    uniform = uniform_configurations(limits, 500, seed=4)
    # Within 0.05 of a critical value: all ten, against ~10 % of uniform targets (the
    # chance that ten uniform ones all are: ~1e-10).
    assert np.all(_critical_gap(q) < 0.05)
    assert np.mean(_critical_gap(uniform) < 0.05) < 0.15


def test_a_one_sample_candidate_is_judged_worse_and_the_incumbent_no_worse(
    planar3r: ServedModel,
) -> None:
    incumbent = planar3r.manifest.defaults
    one = incumbent.model_copy(update={"num_samples": 1})
    verdict = SMALL(planar3r, one, incumbent)
    assert verdict.candidate["count_right"] < verdict.incumbent["count_right"]
    assert verdict.tests["count_right"].worse
    assert any(w.startswith("count right") for w in verdict.worse)
    assert "worse than the incumbent" in verdict.summary()
    same = SMALL(planar3r, incumbent, incumbent)
    assert same.no_worse and same.candidate == same.incumbent


def test_a_seed_offset_draws_the_candidate_from_other_seeds(
    planar3r: ServedModel, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    incumbent = planar3r.manifest.defaults
    few = incumbent.model_copy(update={"num_samples": 3})  # so that draws differ in figures
    verdict = SMALL(planar3r, few, few, candidate_seed_offset=1000, draws=2)
    assert verdict.draws == 2
    q_targets = judging.judged_configurations(planar3r, 12, 4, judging.REPORT_SEED)
    truths = [ground_truth(planar3r, q, judging.REPORT_SEED + i) for i, q in enumerate(q_targets)]
    served = serving(planar3r, few)
    right = {}
    for offset, figures in ((1000, verdict.candidate), (0, verdict.incumbent)):
        seeds = [(i + offset, i + offset + judging.DRAW_SEED_STRIDE) for i in range(16)]
        answers = [
            [served_target(served, q, 3, seed=s) for s in pair]
            for q, pair in zip(q_targets, seeds, strict=True)
        ]
        flat = [a for pair in answers for a in pair]
        assert judging.figures(planar3r, flat, [t for t in truths for _ in (0, 1)]) == figures
        right[offset] = np.array([
            [judging.measure(a, t, planar3r.limits.periodic).right for a in pair]
            for pair, t in zip(answers, truths, strict=True)
        ], dtype=float)  # fmt: skip
    gains = right[1000].mean(axis=1) - right[0].mean(axis=1)
    assert verdict.tests["count_right"].gain == pytest.approx(gains.mean(), rel=1e-12)
    assert verdict.candidate != verdict.incumbent  # other draws: other answers
    assert "the candidate's sampling seeds moved by 1000" in verdict.summary()

    out = tmp_path / "self.json"
    smm_train(["judge", "--model", "planar3r-position", "--candidate", "{}",
               "--candidate-seed-offset", "7", "--targets", "4", "--near-singular", "1",
               "--out", str(out)])  # fmt: skip
    record = json.loads(out.read_text())
    assert record["candidate_seed_offset"] == 7
    assert record["candidate_defaults"] == record["incumbent_defaults"]
    assert "seeds moved by 7" in record["verdict"]
    capsys.readouterr()
    with pytest.raises(SystemExit):
        smm_train(["judge", "--model", "planar3r-position", "--candidate", "{}",
                   "--candidate-seed-offset", "7", "--write"])  # fmt: skip
    assert "leave out --candidate-seed-offset" in capsys.readouterr().err


def test_judged_defaults_keep_the_incumbent_unless_no_worse(planar3r: ServedModel) -> None:
    incumbent = planar3r.manifest.defaults
    reworded = incumbent.model_copy(update={"reasons": {"sampler": "other words"}})
    assert judging.judged_defaults(planar3r, reworded, incumbent) == reworded

    one = incumbent.model_copy(
        update={"num_samples": 1, "reasons": {**incumbent.reasons, "new_axis": "measured"}}
    )
    kept = judging.judged_defaults(planar3r, one, incumbent, targets=12)  # and 1 near-singular
    assert kept.model_dump(exclude={"reasons"}) == incumbent.model_dump(exclude={"reasons"})
    assert "num_samples 1000 -> 1" in kept.reasons["judged"]
    assert "does not serve" in kept.reasons["judged"]
    assert "12 report targets (seed 7) and 1 near-singular ones" in kept.reasons["judged"]
    assert {k: kept.reasons[k] for k in incumbent.reasons if k != "judged"} == {
        k: v for k, v in incumbent.reasons.items() if k != "judged"
    }
    assert kept.reasons["new_axis"] == "the sweep's choice, not served (reasons.judged): measured"

    unknown = replace(planar3r, manifest=planar3r.manifest.model_copy(update={"robot": "twin3r"}))
    unjudged = judging.judged_defaults(unknown, one, incumbent)
    assert unjudged.num_samples == 1
    assert unjudged.reasons["judged"].startswith("not judged: no exact reference for robot")


def test_the_cli_judges_the_paper_configuration_or_a_json_change(
    planar3r: ServedModel, tmp_path: Path
) -> None:
    served = planar3r.manifest.defaults
    paper = judging.candidate_defaults(served, "paper")
    assert (paper.sampler.flow, paper.sampler.steps, paper.sampler.precision) == (
        "base", 100, "float32",
    )  # fmt: skip
    assert (paper.sampler.time_power, paper.correction_steps) == (1.0, 3)
    assert paper.connectivity == served.connectivity and paper.num_samples == served.num_samples
    changed = judging.candidate_defaults(served, '{"sampler": {"steps": 2}, "correction_steps": 4}')
    assert changed.sampler == served.sampler.model_copy(update={"steps": 2})
    assert changed.correction_steps == 4 and changed.damping == served.damping
    # A group is merged into the served one, whichever it is.
    finer = judging.candidate_defaults(served, '{"connectivity": {"path_spacing_rad": 0.03}}')
    assert finer.connectivity == served.connectivity.model_copy(update={"path_spacing_rad": 0.03})
    assert finer.sampler == served.sampler
    for bad in ("fast", "[1]"):
        with pytest.raises(ValueError, match="--candidate: "):
            judging.candidate_defaults(served, bad)

    out = tmp_path / "judgement.json"
    smm_train(["judge", "--model", "planar3r-position", "--candidate", '{"num_samples": 1}',
                  "--targets", "6", "--near-singular", "2", "--out", str(out)])  # fmt: skip
    record = json.loads(out.read_text())
    assert record["candidate_argument"] == '{"num_samples": 1}'
    assert record["candidate_defaults"]["num_samples"] == 1
    assert record["incumbent_defaults"]["num_samples"] == served.num_samples
    assert set(record["candidate"]) == set(record["incumbent"])  # the figures of each
    assert (record["targets"], record["near_singular_targets"]) == (6, 2)
    assert any(w.startswith("count right") for w in record["worse"])
    assert record["verdict"].startswith("worse than the incumbent on 6 report targets")


def test_a_candidate_judged_no_worse_serves_marking_what_it_changed(
    planar3r: ServedModel, tmp_path: Path
) -> None:
    served = planar3r.manifest.defaults
    candidate = judging.candidate_defaults(served, '{"correction_steps": 10}')
    no_worse = judging.Judgement(
        targets=6, near_singular_targets=2, seed=7, candidate={"count_right": 1.0},
        incumbent={"count_right": 1.0}, worse=[], draws=4,
    )  # fmt: skip
    serving = judging.served_candidate(served, candidate, no_worse, "the candidate X")
    assert serving.model_dump(exclude={"reasons"}) == candidate.model_dump(exclude={"reasons"})
    assert serving.reasons["correction_steps"] == (
        "set by the judged candidate (reasons.judged), not by this rule: "
        + served.reasons["correction_steps"]
    )
    unchanged = set(served.reasons) - {"correction_steps", judging.JUDGED}
    assert {key: serving.reasons[key] for key in unchanged} == {
        key: served.reasons[key] for key in unchanged
    }
    # A field of a group marks the reason of that field, or else of its group, only.
    unmarked = served.model_copy(update={"reasons": {**served.reasons, "sampler": "a rule"}})
    rounds = judging.served_candidate(
        unmarked, judging.candidate_defaults(unmarked, '{"sampler": {"round_samples": 64}}'),
        no_worse, "Z",
    )  # fmt: skip
    assert {key for key in unmarked.reasons if rounds.reasons[key] != unmarked.reasons[key]} == {
        "sampler", judging.JUDGED,
    }  # fmt: skip
    precision = judging.served_candidate(
        served, judging.candidate_defaults(served, '{"sampler": {"precision": "float32"}}'),
        no_worse, "P",
    )  # fmt: skip
    assert precision.reasons["sampler_precision"].startswith("set by the judged candidate")
    assert precision.reasons["sampler"] == served.reasons["sampler"]
    # The verdicts that set the served defaults stay, before this one.
    *earlier, verdict = serving.reasons[judging.JUDGED].split(judging.JUDGED_SEPARATOR)
    assert earlier == served.reasons[judging.JUDGED].split(judging.JUDGED_SEPARATOR)
    assert verdict == (
        f"the candidate X, changing correction_steps {served.correction_steps} -> 10, serves: "
        "no worse than the incumbent on 6 report targets (seed 7) and 2 near-singular ones, "
        "4 draws each, against the exact SMMs"
    )
    with pytest.raises(ValueError, match="judged worse does not serve"):
        judging.served_candidate(served, candidate, replace(no_worse, worse=["count right"]), "X")
    # A second judged change of the same field: the mark is not repeated, and the verdict
    # that set the incumbent stays, before the new one.
    again = judging.served_candidate(
        serving, judging.candidate_defaults(serving, '{"correction_steps": 12}'), no_worse, "Y"
    )
    assert again.reasons["correction_steps"] == serving.reasons["correction_steps"]
    *first, second = again.reasons[judging.JUDGED].split(judging.JUDGED_SEPARATOR)
    assert judging.JUDGED_SEPARATOR.join(first) == serving.reasons[judging.JUDGED]
    assert second.startswith("Y, changing correction_steps 10 -> 12, serves: no worse")

    # The CLI writes only a candidate judged no worse, into the model it judged.
    models = tmp_path / "models"
    for part in ("planar3r-position", "robots"):  # the model and the URDF it names
        shutil.copytree(REPO_MODELS_DIR / part, models / part)
    manifest = models / "planar3r-position" / MANIFEST_FILE
    before = manifest.read_text()
    small = ["--model", "planar3r-position", "--targets", "4", "--near-singular", "1",
             "--models-dir", str(models), "--write"]  # fmt: skip
    with pytest.raises(SystemExit, match="not written: worse than the incumbent"):
        smm_train(["judge", *small, "--candidate", '{"num_samples": 1}'])
    assert manifest.read_text() == before
    with pytest.raises(SystemExit):  # the candidate serves as given, at its own N
        smm_train(["judge", *small, "--candidate", '{"num_samples": 1}', "--num-samples", "10"])
    same = f'{{"correction_steps": {served.correction_steps}}}'  # what serves: no worse
    smm_train(["judge", *small, "--candidate", same])
    written = Manifest.model_validate_json(manifest.read_text()).defaults
    assert written.model_dump(exclude={"reasons"}) == served.model_dump(exclude={"reasons"})
    # Only what the manifest set and the candidate changed is written: no field that
    # neither sets appears (a sampler field as null, say).
    assert written.model_fields_set == served.model_fields_set
    assert written.sampler.model_fields_set == served.sampler.model_fields_set
    assert None not in json.loads(manifest.read_text())["defaults"]["sampler"].values()
    last_verdict = written.reasons[judging.JUDGED].split(judging.JUDGED_SEPARATOR)[-1]
    assert last_verdict.startswith(
        f"the candidate {same} (smm-train judge --model planar3r-position "
        f"--candidate '{same}' --write), changing nothing, serves: no worse"
    )
    assert (REPO_MODELS_DIR / "planar3r-position" / MANIFEST_FILE).read_text() != (
        manifest.read_text()
    )  # the bundled model untouched


class _Collapsing:
    """A velocity field that drives every sample to the same corner of the envelope."""

    def __call__(self, q_t: np.ndarray, t: np.ndarray, condition: np.ndarray) -> np.ndarray:
        return np.full_like(q_t, 50.0)


def test_a_candidate_network_is_judged_at_its_own_defaults(
    planar3r: ServedModel, iiwa14_pose_model: ServedModel, tmp_path: Path
) -> None:
    served = planar3r.manifest.defaults
    same = SMALL(planar3r, served, served, candidate_model=planar3r)
    assert same.no_worse and same.candidate == same.incumbent
    collapsing = replace(
        planar3r,
        networks={name: _Collapsing() for name in planar3r.networks},
    )
    collapsed = SMALL(planar3r, served, served, candidate_model=collapsing)
    assert any(w.startswith("count right") for w in collapsed.worse)
    # Exact points with no answer near them at all: coverage is unbounded, and worse.
    assert collapsed.candidate["coverage_p95_rad"] == float("inf")
    assert any(w.startswith("coverage p95") for w in collapsed.worse)
    with pytest.raises(ValueError, match="differs from planar3r-position in robot"):
        judging.check_same_problem(iiwa14_pose_model, planar3r)

    models = tmp_path / "models"
    for part in ("planar3r-position", "robots"):
        shutil.copytree(REPO_MODELS_DIR / part, models / part)
    out = tmp_path / "judgement.json"
    small = ["--model", "planar3r-position", "--targets", "3", "--near-singular", "1"]
    smm_train(["judge", *small, "--candidate-model-dir", str(models / "planar3r-position"),
                  "--out", str(out)])  # fmt: skip
    record = json.loads(out.read_text())
    assert record["candidate_model"] == planar3r.reference and record["worse"] == []
    # The candidate network at the served defaults so changed: one sample is worse.
    smm_train(["judge", *small, "--candidate-model-dir", str(models / "planar3r-position"),
                  "--candidate", '{"num_samples": 1}', "--out", str(out)])  # fmt: skip
    record = json.loads(out.read_text())
    assert record["candidate_defaults"]["num_samples"] == 1
    assert any(w.startswith("count right") for w in record["worse"])
    with pytest.raises(SystemExit):  # neither a candidate nor a network
        smm_train(["judge", *small])
    # --write: a candidate network judged worse leaves the model as it was ...
    candidate = tmp_path / "candidate" / "planar3r-position"
    for part in ("planar3r-position", "robots"):
        shutil.copytree(models / part, candidate.parent / part)
    (candidate / "manifest.json").write_text(
        (candidate / "manifest.json").read_text().replace('"seed": 42', '"seed": 43')
    )  # a manifest this directory's own, to tell the two apart
    served_manifest = (models / "planar3r-position" / "manifest.json").read_text()
    with pytest.raises(SystemExit):
        smm_train(["judge", *small, "--models-dir", str(models), "--candidate-model-dir",
                   str(candidate), "--candidate", '{"num_samples": 1}', "--write"])  # fmt: skip
    assert (models / "planar3r-position" / "manifest.json").read_text() == served_manifest
    # ... and one judged no worse takes its place, with the verdict in its reasons.
    smm_train(["judge", *small, "--models-dir", str(models), "--candidate-model-dir",
               str(candidate), "--write"])  # fmt: skip
    written = json.loads((models / "planar3r-position" / "manifest.json").read_text())
    assert written["training"]["config"]["seed"] == 43
    assert f"--candidate-model-dir {candidate} --write" in written["defaults"]["reasons"]["judged"]
    for name in ("flow.onnx", "chain.json", "kinematics.onnx"):
        assert (models / "planar3r-position" / name).read_bytes() == (candidate / name).read_bytes()
    assert not list(models.glob(".planar3r-position.*"))
