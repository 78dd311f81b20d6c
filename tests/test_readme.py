"""The README's Python blocks run as written, in order, from the repository root."""

import re

import pytest

from .conftest import ROOT


@pytest.mark.slow
def test_readme_python_blocks_run_in_order(monkeypatch, capsys):
    monkeypatch.chdir(ROOT)
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
    assert len(blocks) >= 2
    namespace = {"__name__": "readme"}
    for i, block in enumerate(blocks):
        exec(compile(block, f"README.md python block {i + 1}", "exec"), namespace)  # noqa: S102
    # the blocks identify the hidden-friction system and add the friction the model lacks
    assert [s.added for s in namespace["result"].refinement.steps] == ["coulomb"]
    assert namespace["boot"].summary().shape[0] == len(namespace["prob"].names)
