"""cvxid — identify nonlinear dynamical systems with time delay, as convex problems.

The main entry points:

* :func:`load_problem` and :func:`run` — a TOML problem spec (a :class:`SystemSpec` of one
  or several equations) in, a :class:`RunResult` out (its :class:`IdentifiedSystem`, and
  for one equation its :class:`IdentifiedModel`);
* :class:`Experiment`, :class:`RegressionBuilder`, :class:`Regression`, :class:`Problem`,
  :class:`Path`, :class:`Bootstrap` — the stages;
* :func:`compare`, :func:`residuals`, :func:`diagnose`, :func:`refine`, :func:`polish` —
  model checking and the output-error fit.
"""

import gc as _gc

_collecting = _gc.isenabled()
_gc.disable()  # importing makes about 190,000 lasting objects and no garbage: the collector's
#               three full walks through them were 0.2 s of a 1.2 s import (measured)
try:
    from cvxid.app.result import RunResult
    from cvxid.app.run import order_search, refine_spec, run
    from cvxid.data.experiment import Experiment, from_frame, load
    from cvxid.data.sensor import sensor_faults, without_faults
    from cvxid.diagnosis.candidates import with_effect
    from cvxid.diagnosis.compare import compare, compare_system
    from cvxid.diagnosis.ranking import diagnose
    from cvxid.diagnosis.refine import refine as refine_model
    from cvxid.diagnosis.residuals import residuals
    from cvxid.errors import CvxidError, CvxidWarning, SolverFailure
    from cvxid.identified import IdentifiedModel, IdentifiedSystem
    from cvxid.identify.bootstrap import Bootstrap
    from cvxid.identify.output_error import polish
    from cvxid.identify.path import Path
    from cvxid.identify.problem import Problem
    from cvxid.model.equation import ModelSpec
    from cvxid.model.library import CATALOGUE, Library, register_effect
    from cvxid.model.system import SystemSpec
    from cvxid.regression.builder import RegressionBuilder, SystemBuilder, build_regression
    from cvxid.regression.regression import Regression
    from cvxid.spec.load import load_problem
finally:
    if _collecting:
        _gc.enable()
    del _gc, _collecting

__version__ = "0.1.0"
__all__ = [
    "Bootstrap", "CATALOGUE", "CvxidError", "CvxidWarning", "Experiment", "IdentifiedModel", "IdentifiedSystem",
    "Library", "ModelSpec", "Path", "Problem", "Regression", "RegressionBuilder", "RunResult", "SolverFailure",
    "SystemBuilder", "SystemSpec", "build_regression", "compare", "compare_system", "diagnose", "from_frame", "load", "load_problem",
    "order_search", "polish", "refine", "refine_spec", "register_effect", "residuals", "run", "sensor_faults",
    "with_effect", "without_faults",
]


def refine(target, *args, **kwargs):
    """The diagnose → add → refit loop: ``refine(spec)`` runs a problem spec with it;
    ``refine(model, train, test)`` runs it on an identified model or system."""
    if isinstance(target, (IdentifiedModel, IdentifiedSystem)):
        return refine_model(target, *args, **kwargs)
    return refine_spec(target, *args, **kwargs)
