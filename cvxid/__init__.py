"""cvxid — identify nonlinear dynamical systems with time delay, as convex problems.

The main entry points:

* :func:`load_problem` and :func:`run` — a TOML problem spec in, a :class:`RunResult` out;
* :class:`Experiment`, :class:`Regression`, :class:`Problem`, :class:`Path` — the stages;
* :func:`compare`, :func:`residuals`, :func:`diagnose`, :func:`refine` — model checking.
"""

from .data import Experiment, from_frame, load
from .diagnostics import compare, diagnose, residuals, with_effect
from .diagnostics import refine as refine_model
from .errors import CvxidError, CvxidWarning, SolverFailure
from .identified import IdentifiedModel
from .library import CATALOGUE, Library, register_effect
from .model import ModelSpec
from .path import Path
from .pipeline import RunResult, refine_spec, run
from .polish import polish
from .problem import Problem
from .problems import load_problem
from .regression import Regression
from .selection import order_search

__version__ = "0.1.0"
__all__ = [
    "CATALOGUE", "CvxidError", "CvxidWarning", "Experiment", "IdentifiedModel", "Library", "ModelSpec", "Path",
    "Problem", "Regression", "RunResult", "SolverFailure", "compare", "diagnose", "from_frame", "load",
    "load_problem", "order_search", "polish", "refine", "refine_spec", "register_effect", "residuals", "run",
    "with_effect",
]


def refine(target, *args, **kwargs):
    """The diagnose → add → refit loop: ``refine(spec)`` runs a problem spec with it;
    ``refine(model, train, test)`` runs it on an identified model."""
    if isinstance(target, IdentifiedModel):
        return refine_model(target, *args, **kwargs)
    return refine_spec(target, *args, **kwargs)
