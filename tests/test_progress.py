"""Progress bars: shown on a terminal for jobs over two seconds, silenced by --quiet."""

import io
import sys
import time

import pytest

from cvxid import progress as progress_module
from cvxid.app.cli import main
from cvxid.progress import DELAY, is_quiet, progress, set_quiet


class Terminal(io.StringIO):
    def isatty(self):
        return True


@pytest.fixture
def terminal(monkeypatch):
    """A terminal as stderr (set in the test's own body: pytest swaps stderr between phases)."""
    screen = Terminal()
    yield lambda: monkeypatch.setattr(sys, "stderr", screen) or screen
    set_quiet(False)


def test_a_bar_shows_on_a_terminal_only_once_its_loop_ran_past_the_delay(terminal, monkeypatch):
    screen = terminal()
    assert DELAY == 2.0
    list(progress(range(3), "quick work"))  # done well within two seconds: nothing printed
    assert screen.getvalue() == ""
    monkeypatch.setattr(progress_module, "DELAY", 0.05)  # the same rule, on a shorter clock
    for _ in progress(range(6), "long work"):
        time.sleep(0.03)
    assert "long work" in screen.getvalue()


def test_quiet_silences_every_bar(terminal):
    terminal()
    set_quiet(True)
    assert is_quiet() and progress(range(3), "work").disable
    assert progress(desc="by hand", total=4).disable
    set_quiet(False)
    assert not progress(range(3), "work").disable
    assert progress(range(3), "work", disable=True).disable


def test_the_cli_quiet_flag_reaches_the_bars(terminal, capsys):
    terminal()
    assert main(["problems", "--quiet"]) == 0 and is_quiet()
    assert main(["problems"]) == 0 and not is_quiet()


def test_no_bar_when_stderr_is_not_a_terminal(monkeypatch):
    monkeypatch.setattr(sys, "stderr", io.StringIO())
    assert progress(range(3), "work").disable
