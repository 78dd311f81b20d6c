"""Errors and warnings that cvxid raises for its users.

A :class:`CvxidError` always says what is wrong, where (the field, file or term) and how to
fix it.  The command line prints its message on one line and exits non-zero, without a
Python traceback.
"""

from __future__ import annotations


class CvxidError(ValueError):
    """A problem with the user's input, spec, data or model (never a bug in cvxid)."""


class SolverFailure(CvxidError):
    """The convex solver did not return an optimal solution."""


class CvxidWarning(UserWarning):
    """Something the user should see: an inaccurate solve, an ill-posed estimate, …"""


class EquationErrorDelayWarning(CvxidWarning):
    """The equation-error (Taylor) estimate of the delay is not one; a later output-error
    polish that estimates the delay supersedes it, and the run then drops the warning."""
