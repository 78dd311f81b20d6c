import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MPLBACKEND", "Agg")
ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"
PAPER_DATA = SHARED_DATA / "paper_duffing_delay_DataMCK.mat"


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


needs_paper_data = pytest.mark.skipif(not PAPER_DATA.is_file(), reason="paper dataset absent")


def cli_error(tmp_path, capsys, text: str) -> str:
    """Run ``cvxid run`` on a spec with ``text``; assert exit 2, one line, no traceback."""
    from cvxid.app.cli import main

    spec = tmp_path / "bad.toml"
    spec.write_text(text)
    assert main(["run", str(spec)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("cvxid: error:") and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    return err


# hidden_friction's simulated records (its inputs, noise 0.001 on x), for specs written by tests
TRAIN_SIMULATED = """[data.train.simulate]
duration = 8.0
dt = 1e-3
x0 = 0.3
seed = 1
noise = { output = 0.001, input = 0.0 }
input = [ { kind = "sine", amplitude = 3.0, omega = 1.9 }, { kind = "sine", amplitude = 2.0, omega = 4.7, phase = 1.0 },
          { kind = "sine", amplitude = 1.5, omega = 8.3, phase = 2.0 } ]"""
TEST_SIMULATED = """[data.test.simulate]
duration = 8.0
dt = 1e-3
x0 = -0.2
seed = 2
noise = { output = 0.001, input = 0.0 }
input = [ { kind = "sine", amplitude = 2.5, omega = 2.9 }, { kind = "sine", amplitude = 2.5, omega = 6.1, phase = 1.0 } ]"""
