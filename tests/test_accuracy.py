"""The accuracy benchmark on small settings (not timed: it checks what the table says)."""

import pytest

from cvxid.spec.load import load_problem
from cvxid.tools.accuracy import accuracy, summary

from .conftest import ROOT


@pytest.mark.slow
def test_exact_delay_with_polish_beats_the_paper_on_noise_free_data():
    frame = accuracy(load_problem(ROOT / "problems" / "duffing_delay.toml"), noises=(0.0,), seeds=1,
                     methods=("paper (true v)", "exact+oe"))
    table = summary(frame)
    paper = abs(table.loc[("paper (true v)", 0.0), "tau error % mean"])
    ours = abs(table.loc[("exact+oe", 0.0), "tau error % mean"])
    assert paper > 1.0  # the Taylor-3 truncation error
    assert ours < 0.05
    assert table.loc[("exact+oe", 0.0), "worst other % mean"] < 0.1
