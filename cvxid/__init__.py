"""cvxid — identify nonlinear dynamical systems with time delay, as convex problems."""

from .data import Experiment, load, load_csv, load_mat
from .errors import CvxidError, CvxidWarning, SolverFailure
from .identified import IdentifiedModel
from .library import CATALOGUE, Library, register_effect
from .model import ModelSpec
from .path import Path
from .problem import Problem
from .regression import Regression

__version__ = "0.1.0"
