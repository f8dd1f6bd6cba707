"""figure_pair: three significant digits when they tell the figures apart, more (up to six)
when they do not, and the two figures always in the order given."""

from training.evaluate.compare import figure_pair


def test_three_digits_when_they_differ_there() -> None:
    assert figure_pair(0.977, 0.973) == "0.977 vs 0.973"
    assert figure_pair(1.48, 1.45) == "1.48 vs 1.45"


def test_more_digits_until_the_figures_print_apart() -> None:
    assert figure_pair(0.017631, 0.017582) == "0.01763 vs 0.01758"
    assert figure_pair(0.0176314, 0.0176309) == "0.0176314 vs 0.0176309"


def test_at_most_six_digits() -> None:
    assert figure_pair(1.0000001, 1.0000002) == "1 vs 1"
    assert figure_pair(2.0, 2.0) == "2 vs 2"
