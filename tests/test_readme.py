"""The README's Python blocks, then those of docs/python.md, run as written and in order."""

import re

import pytest

from .conftest import ROOT


def blocks(path):
    return re.findall(r"```python\n(.*?)```", path.read_text(), re.S)


@pytest.mark.slow
def test_readme_and_docs_python_blocks_run_in_order(monkeypatch, capsys, tmp_path):
    monkeypatch.chdir(tmp_path)  # from any folder: the blocks need only the installed package
    namespace = {"__name__": "readme"}
    sources = [("README.md", ROOT / "README.md"), ("docs/python.md", ROOT / "docs" / "python.md")]
    for label, path in sources:
        found = blocks(path)
        assert found, f"{label} has no python block"
        for i, block in enumerate(found):
            exec(compile(block, f"{label} python block {i + 1}", "exec"), namespace)  # noqa: S102
    # the blocks identify the hidden-friction system and add the friction the model lacks
    assert [s.added for s in namespace["result"].refinement.steps] == ["coulomb"]
    assert namespace["boot"].summary().shape[0] == len(namespace["prob"].names)
    assert namespace["cmp"].fit_percent >= namespace["cmp"].record_fit_percent
