"""The shipped problems: listed by ``cvxid problems``, run by name from any folder."""

from cvxid.app.cli import main
from cvxid.spec.shipped import problems_table, resolve_spec, shipped_problems

from .conftest import ROOT


def test_every_spec_in_problems_is_shipped_and_listed_with_a_summary(capsys):
    names = {p.stem for p in (ROOT / "problems").glob("*.toml")}
    assert set(shipped_problems()) == names
    table = problems_table()
    assert set(table.index) == names and (table["what it shows"].str.len() > 20).all()
    assert table.loc["hidden_friction", "data"] == "simulated"
    assert main(["problems"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in names) and "cvxid run NAME" in out


def test_a_name_finds_the_shipped_spec_from_any_folder_and_a_file_wins(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert resolve_spec("hidden_friction") == shipped_problems()["hidden_friction"]
    assert resolve_spec("hidden_friction.toml") == shipped_problems()["hidden_friction"]
    (tmp_path / "hidden_friction.toml").write_text("name = 'mine'\n")
    assert resolve_spec("hidden_friction.toml").resolve() == (tmp_path / "hidden_friction.toml").resolve()


def test_an_unknown_name_lists_the_shipped_problems(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["run", "hidden_frictoin"]) == 2
    err = capsys.readouterr().err
    assert "spec file not found: hidden_frictoin" in err and "hidden_friction" in err and "cvxid problems" in err
    assert main(["run", "sub/hidden_friction.toml"]) == 2  # a path is a path, never a shipped name
