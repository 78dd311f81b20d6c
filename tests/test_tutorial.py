"""The tutorial notebook runs as stored, teaches what it says, and is stored without outputs."""

import nbformat
import pytest

from .conftest import ROOT

NOTEBOOK = ROOT / "examples" / "tutorial.ipynb"

CHECKS = '''
# the test's own cell, appended after the tutorial's: what the text claims, measured
assert np.max(np.abs(from_x - from_xdd)) < 1e-8 and np.max(np.abs(twice - x)) > 1.0
chosen = {n for n, s in zip(path.names, path.best("1se").support) if s}
assert chosen == {"x''", "x", "x'", "sign(x')"}, chosen
signs = dict(zip(rows.names, signed.coefficients))
assert dict(zip(rows.names, free.coefficients))["x'|x'|"] < 0 <= signs["x'|x'|"]
assert abs(signs["x'"] - 0.4) < abs(dict(zip(rows.names, free.coefficients))["x'"] - 0.4)
assert [s.added for s in loop.steps] == ["coulomb"] and loop.steps[0].test_mse_after < 0.1 * loop.steps[0].test_mse_before
low, high = equation_profile.interval
assert high - low > 0.1                                # the equation error cannot pin the delay down ...
assert abs(polished.parameters["tau"] - 0.15) < 0.005  # ... the simulation error can
assert comparison.fit_percent > 99 and comparison.fit_percent > comparison.record_fit_percent
'''


def test_the_notebook_is_stored_without_outputs():
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    code = [c for c in notebook.cells if c.cell_type == "code"]
    assert code and all(not c.outputs and c.execution_count is None for c in code)


@pytest.mark.slow
def test_the_tutorial_runs_and_its_claims_hold(tmp_path):
    from nbclient import NotebookClient

    notebook = nbformat.read(NOTEBOOK, as_version=4)
    notebook.cells.append(nbformat.v4.new_code_cell(CHECKS))
    # from a folder that is not the repository: the tutorial needs only the installed package
    NotebookClient(notebook, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    errors = [o for c in notebook.cells if c.cell_type == "code" for o in c.outputs if o.output_type == "error"]
    assert not errors
    warnings = [o.text for c in notebook.cells[:-1] if c.cell_type == "code" for o in c.outputs
                if o.output_type == "stream" and o.name == "stderr"]
    assert not warnings, warnings  # a tutorial that prints warnings teaches the reader to ignore them
