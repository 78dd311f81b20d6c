"""State symbols: a coordinate ``x``, its velocity ``x'``, and how they print in LaTeX."""

from __future__ import annotations

GREEK = {"alpha", "beta", "gamma", "delta", "epsilon", "zeta", "eta", "theta", "iota", "kappa", "lambda", "mu",
         "nu", "xi", "pi", "rho", "sigma", "tau", "upsilon", "phi", "chi", "psi", "omega", "Gamma", "Delta", "Theta",
         "Lambda", "Xi", "Pi", "Sigma", "Phi", "Psi", "Omega"}


def velocity_symbol(coordinate: str) -> str:
    return coordinate + "'"


def latex_symbol(symbol: str) -> str:
    """``theta'`` as ``\\dot{\\theta}``: Greek names become letters, one or two primes dots."""
    base = symbol.rstrip("'")
    dots = len(symbol) - len(base)
    base = "\\" + base if base in GREEK else base
    return {0: base, 1: rf"\dot{{{base}}}", 2: rf"\ddot{{{base}}}"}.get(dots, f"{base}^{{({dots})}}")
