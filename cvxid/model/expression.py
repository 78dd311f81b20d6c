r"""A user's term as an expression: ``sin(theta)``, ``cos(theta) * theta'``, ``tanh(50 x')``,
``exp(-x^2)``, ``abs(x)^1.5``.

The text is read by Python's parser (``ast.parse(mode="eval")``): nothing is evaluated, and a
tree is accepted only if each node is on a short list:

* numbers; the model's coordinates (``theta``) and their velocities (``theta'``);
* ``+ - * /`` and powers (``^`` or ``**``), unary minus;
* the functions ``sin cos tanh exp abs sign sqrt``.

The accepted tree becomes a *program* for a stack machine, a few integer codes and numbers:
the same program gives the regression column (numpy, :meth:`Program.evaluate`) and the
simulation's right-hand side (the compiled RK4 kernel of :mod:`cvxid.simulate`), so a user's
term runs as fast as a built-in one and is written to JSON by its text alone.
"""

from __future__ import annotations

import ast
import re
from dataclasses import dataclass

import numpy as np

from cvxid.errors import CvxidError
from cvxid.model.symbols import latex_symbol

# the stack machine's operations (the compiled kernel reads the same codes)
CONST, POSITION, VELOCITY = 0, 1, 2
ADD, SUB, MUL, DIV, POW = 3, 4, 5, 6, 7
NEG, SIN, COS, TANH, EXP, ABS, SIGN, SQRT = 8, 9, 10, 11, 12, 13, 14, 15

FUNCTIONS = {"sin": SIN, "cos": COS, "tanh": TANH, "exp": EXP, "abs": ABS, "sign": SIGN, "sqrt": SQRT}
UNARY = {NEG: np.negative, SIN: np.sin, COS: np.cos, TANH: np.tanh, EXP: np.exp, ABS: np.abs, SIGN: np.sign,
         SQRT: np.sqrt}
BINARY = {ast.Add: ADD, ast.Sub: SUB, ast.Mult: MUL, ast.Div: DIV, ast.Pow: POW}
BINARY_NUMPY = {ADD: np.add, SUB: np.subtract, MUL: np.multiply, DIV: np.divide, POW: np.power}
LATEX = {SIN: r"\sin", COS: r"\cos", TANH: r"\tanh", EXP: r"\exp", SIGN: r"\operatorname{sign}"}
MAX_LENGTH = 200
"""Longest expression text accepted."""

_VELOCITY = "__velocity"


@dataclass(frozen=True)
class Program:
    """A postfix program: ``ops[i]`` with its number ``args[i]`` (a constant, or a
    coordinate's index for ``POSITION``/``VELOCITY``)."""

    ops: np.ndarray
    args: np.ndarray

    def evaluate(self, positions: list[np.ndarray], velocities: list[np.ndarray],
                 poles: list | None = None) -> np.ndarray:
        """The program on arrays (each coordinate's position and velocity); ``poles``, when
        given, receives every divisor and every base of a negative power (where the term
        is unbounded when they reach 0)."""
        stack = []
        with np.errstate(all="ignore"):
            for op, arg in zip(self.ops, self.args):
                if op == CONST:
                    stack.append(np.float64(arg))
                elif op == POSITION:
                    stack.append(positions[int(arg)])
                elif op == VELOCITY:
                    stack.append(velocities[int(arg)])
                elif op <= POW:
                    right, left = stack.pop(), stack.pop()
                    if poles is not None and (op == DIV or op == POW and np.any(np.asarray(right) < 0)):
                        poles.append(right if op == DIV else left)
                    stack.append(BINARY_NUMPY[int(op)](left, right))
                else:
                    stack.append(UNARY[int(op)](stack.pop()))
        return stack[0]

    def signed(self) -> tuple[int, "Program"] | None:
        r"""``(c, factor)`` when the program is :math:`\operatorname{sign}(\dot q_c)` times a
        factor that holds no sign (a Stribeck friction, ``sign(x') * exp(-(x'/v_s)^2)``):
        the integrator treats it as a friction whose bound is the factor; else None."""
        ops, args = self.ops, self.args
        if ops.size < 4 or ops[-1] != MUL:
            return None
        if ops[0] == VELOCITY and ops[1] == SIGN:
            c, body = int(args[0]), slice(2, ops.size - 1)
        elif ops[-3] == VELOCITY and ops[-2] == SIGN:
            c, body = int(args[-3]), slice(0, ops.size - 3)
        else:
            return None
        factor = Program(ops[body], args[body])
        return (c, factor) if factor._single() and not np.any(factor.ops == SIGN) else None

    def _single(self) -> bool:
        """Whether the program leaves one value, never reading below its start."""
        depth = 0
        for op in self.ops:
            depth += 1 if op <= VELOCITY else (-1 if op <= POW else 0)
            if depth < 1:
                return False
        return depth == 1

    def crossings(self, positions: list[np.ndarray], velocities: list[np.ndarray]) -> np.ndarray:
        """The samples after which a divisor, or the base of a negative power, changes sign
        or is 0 (where the term may be unbounded), in order."""
        poles = []
        self.evaluate(positions, velocities, poles)
        found = [np.flatnonzero(np.sign(p[:-1]) * np.sign(p[1:]) <= 0) for p in poles if np.ndim(p) == 1]
        return np.unique(np.concatenate(found)) if found else np.zeros(0, np.int64)


@dataclass(frozen=True)
class Parsed:
    """An expression read and checked: its normalised text, LaTeX, program and the state
    symbols it reads (``theta``, ``theta'``)."""

    text: str
    latex: str
    program: Program
    symbols: frozenset[str]


def parse_expression(text: str, coordinates: tuple[str, ...]) -> Parsed:
    """Read ``text`` as an expression of the ``coordinates`` and their velocities (see the
    module docstring); a :class:`~cvxid.errors.CvxidError` names what is not allowed."""
    raw = str(text).strip()
    if len(raw) > MAX_LENGTH:
        raise CvxidError(f"term '{raw[:40]}…' is longer than {MAX_LENGTH} characters")
    if "''" in raw:
        raise CvxidError(f"term '{raw}': an acceleration (x'') is the inertia term, not a term of g(x, x')")
    source = re.sub(r"([A-Za-z_][A-Za-z_0-9]*)'", rf"\1{_VELOCITY}", raw).replace("^", "**")
    source = re.sub(r"(?<=[0-9A-Za-z_)])\s+(?=[A-Za-z_])", " * ", source)  # "50 x'" is 50 * x'
    try:
        tree = ast.parse(source, mode="eval").body
    except SyntaxError:
        raise CvxidError(f"cannot read term '{raw}' as an expression (write it like sin(theta), x' * abs(x'), "
                         "tanh(50 * x'), exp(-x^2))") from None
    ops, args, symbols = [], [], set()
    latex = _compile(tree, raw, coordinates, ops, args, symbols)
    program = Program(np.array(ops, np.int64), np.array(args, float))
    text = ast.unparse(tree).replace(" ** ", "^").replace(_VELOCITY, "'")
    return Parsed(text, latex, program, frozenset(symbols))


def _grouped(node, latex: str) -> str:
    """``latex`` in parentheses when ``node`` is a sum or a difference."""
    if isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Add, ast.Sub)):
        return f"\\left({latex}\\right)"
    return latex


def _compile(node, raw: str, coordinates, ops: list, args: list, symbols: set) -> str:
    """Append ``node``'s postfix program; return its LaTeX."""
    def emit(op, arg=0.0):
        ops.append(op)
        args.append(float(arg))

    def refuse(what: str):
        velocities = ", ".join(f"{c}'" for c in coordinates)
        raise CvxidError(
            f"term '{raw}': {what} is not allowed; a term is built from numbers, the coordinates "
            f"({', '.join(coordinates)}) and their velocities ({velocities}), + - * / ^ and the functions "
            f"{', '.join(FUNCTIONS)}")

    if isinstance(node, ast.Constant):
        if isinstance(node.value, bool) or not isinstance(node.value, (int, float)) or not abs(node.value) < 1e300:
            refuse(f"the constant {float(node.value) if isinstance(node.value, float) else node.value!r}")
        emit(CONST, node.value)
        return f"{node.value:g}"
    if isinstance(node, ast.Name):
        velocity = node.id.endswith(_VELOCITY)
        name = node.id[: -len(_VELOCITY)] if velocity else node.id
        if name not in coordinates:
            refuse(f"the name '{name}'" + (" (a function needs parentheses)" if name in FUNCTIONS else ""))
        emit(VELOCITY if velocity else POSITION, coordinates.index(name))
        symbols.add(name + ("'" if velocity else ""))
        return latex_symbol(name + ("'" if velocity else ""))
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        inner = _compile(node.operand, raw, coordinates, ops, args, symbols)
        if isinstance(node.op, ast.USub):
            emit(NEG)
            return f"-{_grouped(node.operand, inner)}"
        return inner
    if isinstance(node, ast.BinOp) and type(node.op) in BINARY:
        left = _compile(node.left, raw, coordinates, ops, args, symbols)
        right = _compile(node.right, raw, coordinates, ops, args, symbols)
        op = BINARY[type(node.op)]
        emit(op)
        if op == POW:
            return f"\\left({left}\\right)^{{{right}}}" if not isinstance(node.left, (ast.Name, ast.Constant)) \
                else f"{left}^{{{right}}}"
        if op == DIV:
            return f"\\frac{{{left}}}{{{right}}}"
        if op == MUL:
            return f"{_grouped(node.left, left)} {_grouped(node.right, right)}"
        return f"{left} {'+' if op == ADD else '-'} {_grouped(node.right, right) if op == SUB else right}"
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and not node.keywords:
        if node.func.id not in FUNCTIONS:
            refuse(f"the function '{node.func.id}'")
        if len(node.args) != 1:
            refuse(f"{node.func.id} with {len(node.args)} arguments")
        inner = _compile(node.args[0], raw, coordinates, ops, args, symbols)
        op = FUNCTIONS[node.func.id]
        emit(op)
        if op == ABS:
            return f"\\left|{inner}\\right|"
        if op == SQRT:
            return f"\\sqrt{{{inner}}}"
        return f"{LATEX[op]}\\left({inner}\\right)"
    refuse(f"'{ast.unparse(node).replace(_VELOCITY, chr(39))}'")
    raise AssertionError  # refuse raised
