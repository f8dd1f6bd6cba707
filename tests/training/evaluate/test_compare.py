"""figure_pair: three significant digits when they tell the figures apart, more (up to six)
when they do not, and the two figures always in the order given. worse_than and
better_than: each figure on its own side by whether more of it is better, equal figures
on neither, a figure either side lacks skipped, coverage p95 within its margin not worse."""

from training.evaluate.compare import better_than, figure_pair, worse_than

PAPER = {"count_right": 0.95, "splits_per_target": 0.05, "merges_per_target": 0.0,
         "recall": 1.0, "coverage_p95_rad": 0.0173}  # fmt: skip


def test_three_digits_when_they_differ_there() -> None:
    assert figure_pair(0.977, 0.973) == "0.977 vs 0.973"
    assert figure_pair(1.48, 1.45) == "1.48 vs 1.45"


def test_more_digits_until_the_figures_print_apart() -> None:
    assert figure_pair(0.017631, 0.017582) == "0.01763 vs 0.01758"
    assert figure_pair(0.0176314, 0.0176309) == "0.0176314 vs 0.0176309"


def test_at_most_six_digits() -> None:
    assert figure_pair(1.0000001, 1.0000002) == "1 vs 1"
    assert figure_pair(2.0, 2.0) == "2 vs 2"


def test_worse_exactly_where_a_figure_is_worse() -> None:
    assert worse_than(PAPER, PAPER) == []
    better = {**PAPER, "count_right": 1.0, "splits_per_target": 0.0, "coverage_p95_rad": 0.01}
    assert worse_than(better, PAPER) == []
    assert worse_than({**PAPER, "coverage_p95_rad": 0.0174}, PAPER) == [
        "coverage p95 rad 0.0174 vs 0.0173"
    ]
    # Within the margin coverage is not worse; beyond it, it is.
    assert worse_than({**PAPER, "coverage_p95_rad": 0.0180}, PAPER, 0.1) == []
    assert worse_than({**PAPER, "coverage_p95_rad": 0.0191}, PAPER, 0.1) != []
    assert worse_than({**PAPER, "merges_per_target": 0.05, "recall": 0.9}, PAPER) == [
        "merges 0.05 vs 0", "recall 0.9 vs 1",
    ]  # fmt: skip
    # A figure the model has not (splits of planar 3R: None) is not compared.
    assert worse_than({**PAPER, "splits_per_target": None}, PAPER) == []


def test_better_is_worse_seen_from_the_other_side() -> None:
    assert better_than(PAPER, PAPER) == []
    mixed = {**PAPER, "count_right": 1.0, "recall": 0.9, "coverage_p95_rad": 0.01}
    assert better_than(mixed, PAPER) == ["count right 1 vs 0.95", "coverage p95 rad 0.01 vs 0.0173"]
    assert worse_than(mixed, PAPER) == ["recall 0.9 vs 1"]
    assert [f.split(" ")[0] for f in better_than(PAPER, mixed)] == ["recall"]
    assert better_than({**PAPER, "splits_per_target": None, "recall": None}, mixed) == []
