"""A fed-back delay's aliases in a narrow-band record (cvxid/identify/aliases.py): a
lightly damped structure with a regenerative feedback (a machine tool's chatter,
``x'' + 1.8 x' + 930 x = f + 30 x(t - 0.6)``, 2.9 periods of delay), from a twelfth
outside check whose runs reported an alias half a period off, the gain's sign flipped,
with a 4 ms interval and no word."""

import json

import numpy as np
import pytest

from cvxid.app.cli import main
from cvxid.app.run import run
from cvxid.identify.aliases import alias_starts
from cvxid.metrics import spectral_peak
from cvxid.spec.load import parse_problem

CHATTER = """name = "chatter"
[truth]
mass = 1.0
coefficients = { "x'" = 1.8, "x" = 930.0 }
delay = { signal = "x", gain = 30.0, tau = 0.6 }
history = "zero"

[data.train.simulate]
duration = 20.0
dt = 1e-3
seed = 1
noise = { output = 0.0005, input = 0.01 }
input = [ { kind = "sine", amplitude = 20.0, omega = 9.0 },
          { kind = "sine", amplitude = 20.0, omega = 21.0, phase = 1.0 },
          { kind = "sine", amplitude = 20.0, omega = 33.0, phase = 2.0 },
          { kind = "sine", amplitude = 20.0, omega = 47.0, phase = 0.5 } ]

[data.test.simulate]
duration = 8.0
dt = 1e-3
seed = 2
noise = { output = 0.0005, input = 0.01 }
input = [ { kind = "sine", amplitude = 20.0, omega = 13.0 }, { kind = "sine", amplitude = 20.0, omega = 38.0, phase = 1.0 } ]

[model.library]
terms = ["x", "x'"]

[model.delay]
signal = "x"
method = "exact"
tau_max = TAU_MAX

[fit]
estimator = "lstsq"
refine = "output_error"
"""


def chatter(tau_max: float):
    import tomllib

    return parse_problem(tomllib.loads(CHATTER.replace("TAU_MAX", str(tau_max))), ".")


def test_the_spectral_peak_is_read_between_bins_and_tells_a_narrow_band_record():
    """A 3.253 Hz sinusoid in noise, 30 s: a Welch bin is 0.067 Hz wide (2 %), the parabola
    through the peak's three bins puts it within 0.1 %, and nearly all the variance is near
    it; twenty sines spread over two decades (a broad-band record) hold little near their
    highest peak, under the narrow-band share (the aliases' fits and finer grid stay off)."""
    from cvxid.identify.output_error import NARROW_SHARE

    t = np.arange(0, 30, 0.002)
    rng = np.random.default_rng(0)
    peak = spectral_peak(np.sin(2 * np.pi * 3.253 * t) + 0.1 * rng.normal(size=t.size), 0.002)
    assert 1 / peak.period == pytest.approx(3.253, rel=1e-3) and peak.share > 0.95
    broad = sum(np.sin(w * t + p) for w, p in zip(np.geomspace(1, 100, 20), rng.uniform(0, 6.3, 20)))
    assert spectral_peak(broad + 0.1 * rng.normal(size=t.size), 0.002).share < NARROW_SHARE


def test_aliases_are_half_periods_apart_and_flip_an_estimated_gain_only():
    both = (-2, -1, 1, 2)
    assert alias_starts(0.5, 0.2, 0.0, 0.8, True, both) == pytest.approx([(0.3, 1), (0.4, -1), (0.6, -1), (0.7, 1)])
    assert alias_starts(0.5, 0.2, 0.0, 0.8, False, both) == pytest.approx([(0.3, 1), (0.7, 1)])  # a given gain: no flip
    assert alias_starts(0.5, 0.2, 0.5, 0.75, True) == pytest.approx([(0.6, -1), (0.7, 1)])  # past 0.5, up to 0.75


def test_a_delay_past_the_range_whose_alias_the_range_holds_is_found_and_said(tmp_path, capsys):
    """Searched up to 0.5 s the polish ends at the alias 0.4979 (gain -33.2), its interval a
    few ms wide and short of the range's top, so no bound warning could fire; the polish's
    aliases past the range find 0.6 and the gain 30 (measured 0.59998, 30.02), and the run
    says to raise tau_max above it."""
    spec = tmp_path / "chatter.toml"
    spec.write_text(CHATTER.replace("TAU_MAX", "0.5"))
    assert main(["run", str(spec), "--quiet", "--out", str(tmp_path / "out")]) == 0
    printed = capsys.readouterr().out
    assert "tau = 0.49" in printed  # (the alias: the range's estimate is unchanged, and said to be one)
    warning = next(line for line in printed.splitlines() if "past the search range" in line)
    assert "(tau_max = 0.5 s)" in warning and "raise [model.delay] tau_max above 0.6" in warning
    longer = json.loads((tmp_path / "out" / "result.json").read_text())["polish"]["longer_delay"]
    assert longer["tau"] == pytest.approx(0.6, rel=2e-3) and longer["gain"] == pytest.approx(30.0, rel=0.02)
    assert longer["rms"] < longer["rms_estimate"] / 2


def test_a_delay_inside_the_range_near_its_top_has_no_longer_alias():
    """Searched up to 0.65 s the polish finds 0.6 and the gain 30, and no delay past the range
    (its aliases at 0.70, 0.80, ...) is said to fit better: a false alarm would send the user
    off to a longer range (a stranger's review: up to 1 s, only one alias was tried)."""
    result = run(chatter(0.65))
    assert result.tau["estimate"] == pytest.approx(0.6, rel=1e-3) and result.polish.longer_delay is None
    assert result.model.physical["gain"] == pytest.approx(30.0, rel=0.02)
    assert not any("past the search range" in w for w in result.warnings)
