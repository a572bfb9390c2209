"""A restricted, vectorised expression evaluator for scene files.

Scene text is never passed to ``eval`` or ``exec``. An expression is parsed
with :mod:`ast`, checked against a whitelist (numbers, arithmetic,
comparisons, ``and``/``or``/``not``, ``a if c else b``, the variables
``x, y, z, t``, the scene's ``params`` by name, and a fixed set of numpy
functions), and compiled into a tree of Python closures that evaluate on
numpy arrays.

Example
-------
>>> e = Expression("0.1*d*cos(2*pi*x/d)", params={"d": 1.0})
>>> e(np.array([[0.0, 0.0]]), t=0.0)
array([0.1])
"""

from __future__ import annotations

import ast
import math
import operator
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

__all__ = ["ARITY", "Expression", "ExpressionError", "FUNCTIONS", "VARIABLES"]


class ExpressionError(ValueError):
    """An expression uses something outside the whitelist, or does not parse."""


#: Whitelisted functions (name → numpy callable).
FUNCTIONS: dict[str, Callable[..., Any]] = {
    "sin": np.sin,
    "cos": np.cos,
    "tan": np.tan,
    "arcsin": np.arcsin,
    "arccos": np.arccos,
    "arctan": np.arctan,
    "arctan2": np.arctan2,
    "atan2": np.arctan2,
    "sinh": np.sinh,
    "cosh": np.cosh,
    "tanh": np.tanh,
    "exp": np.exp,
    "log": np.log,
    "log10": np.log10,
    "sqrt": np.sqrt,
    "abs": np.abs,
    "sign": np.sign,
    "floor": np.floor,
    "ceil": np.ceil,
    "minimum": np.minimum,
    "maximum": np.maximum,
    "min": np.minimum,
    "max": np.maximum,
    "where": np.where,
    "heaviside": lambda a: np.heaviside(a, 0.5),
    "hypot": np.hypot,
    "mod": np.mod,
}
#: Number of arguments of each function of :data:`FUNCTIONS` (the rest take one).
#: Checked when an expression is compiled: numpy's ufuncs would read a surplus
#: argument as their output array.
ARITY: dict[str, int] = {
    **dict.fromkeys(("arctan2", "atan2", "minimum", "maximum", "min", "max", "hypot", "mod"), 2),
    "where": 3,
}
#: Names always defined.
CONSTANTS: dict[str, float] = {"pi": math.pi, "e": math.e}
#: Coordinate / time variables.
VARIABLES = ("x", "y", "z", "t")

_BINOPS = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
    ast.Pow: operator.pow,
    ast.Mod: np.mod,
}
_UNARY = {ast.UAdd: operator.pos, ast.USub: operator.neg}
_CMP = {
    ast.Lt: np.less,
    ast.LtE: np.less_equal,
    ast.Gt: np.greater,
    ast.GtE: np.greater_equal,
    ast.Eq: np.equal,
    ast.NotEq: np.not_equal,
}
#: What evaluating a whitelisted tree can raise on user input: Python float arithmetic
#: (``1/0``, ``9.0**9**9``), a complex power (``(-1)**0.5``) that is not a real number.
_EVAL_ERRORS = (ArithmeticError, TypeError, ValueError)
_MAX_LEN = 2000
_MAX_NODES = 500

Env = dict[str, Any]
Node = Callable[[Env], Any]


class Expression:
    """A compiled scene expression.

    Parameters
    ----------
    text:
        The expression, e.g. ``"sin(omega*t)*(cos(x)+1)"``; a plain number is
        accepted too.
    params:
        Named numbers usable in the expression.
    where:
        What to name in error messages (e.g. the scene key).
    """

    def __init__(
        self,
        text: str | float | int,
        params: Mapping[str, float] | None = None,
        where: str = "expression",
    ):
        self.where = where
        self.params = dict(params or {})
        if isinstance(text, bool):
            raise ExpressionError(f"{where}: expected an expression or a number, got a boolean")
        if isinstance(text, int | float):
            self.text = repr(float(text))
        elif isinstance(text, str):
            self.text = text
        else:
            raise ExpressionError(
                f"{where}: expected an expression string or a number, got {type(text).__name__}"
            )
        if len(self.text) > _MAX_LEN:
            raise ExpressionError(f"{where}: expression longer than {_MAX_LEN} characters")
        try:
            tree = ast.parse(self.text.strip(), mode="eval")
        except SyntaxError as exc:
            raise ExpressionError(f"{where}: cannot parse {self.text!r} ({exc.msg})") from None
        count = sum(1 for _ in ast.walk(tree))
        if count > _MAX_NODES:
            raise ExpressionError(f"{where}: expression too large ({count} nodes)")
        self.names: set[str] = set()
        self._fn = self._compile(tree.body)
        self.constant = not (self.names & set(VARIABLES))

    # -- compilation ---------------------------------------------------------
    def _err(self, what: str) -> ExpressionError:
        return ExpressionError(f"{self.where}: {what} is not allowed in {self.text!r}")

    def _compile(self, node: ast.AST) -> Node:
        """Check ``node`` against the whitelist and compile it into a closure of an env."""
        compiler = _COMPILERS.get(type(node))
        if compiler is not None:
            return compiler(self, node)
        if isinstance(node, ast.Attribute):
            raise self._err(f"attribute access '.{node.attr}'")
        if isinstance(node, ast.Subscript):
            raise self._err("subscripting")
        raise self._err(f"the syntax {type(node).__name__}")

    def _constant(self, node: ast.Constant) -> Node:
        """A numeric literal (booleans, strings, ... refused)."""
        if isinstance(node.value, bool) or not isinstance(node.value, int | float):
            raise self._err(f"the literal {node.value!r}")
        v = float(node.value)
        return lambda env: v

    def _name(self, node: ast.Name) -> Node:
        """A variable (read from the env), a param or a constant (folded to its value)."""
        name = node.id
        if name.startswith("_"):
            raise self._err(f"the name {name!r}")
        if name in VARIABLES:
            self.names.add(name)
            return lambda env: env[name]
        if name in self.params:
            self.names.add(name)
            v = float(self.params[name])
            return lambda env: v
        if name in CONSTANTS:
            v = CONSTANTS[name]
            return lambda env: v
        if name in FUNCTIONS:
            raise self._err(f"the function {name!r} without a call")
        raise ExpressionError(
            f"{self.where}: unknown name {name!r} in {self.text!r} "
            f"(known: x, y, z, t, params: {', '.join(sorted(self.params)) or 'none'})"
        )

    def _binop(self, node: ast.BinOp) -> Node:
        """An arithmetic operator of :data:`_BINOPS`."""
        op = _BINOPS.get(type(node.op))
        if op is None:
            raise self._err(f"the operator {type(node.op).__name__}")
        a, b = self._compile(node.left), self._compile(node.right)
        return lambda env: op(a(env), b(env))

    def _unaryop(self, node: ast.UnaryOp) -> Node:
        """``not`` (elementwise) or a sign of :data:`_UNARY`."""
        if isinstance(node.op, ast.Not):
            a = self._compile(node.operand)
            return lambda env: np.logical_not(a(env))
        op = _UNARY.get(type(node.op))
        if op is None:
            raise self._err(f"the operator {type(node.op).__name__}")
        a = self._compile(node.operand)
        return lambda env: op(a(env))

    def _boolop(self, node: ast.BoolOp) -> Node:
        """``and`` / ``or``, elementwise, reduced left to right."""
        parts = [self._compile(v) for v in node.values]
        red = np.logical_and if isinstance(node.op, ast.And) else np.logical_or

        def boolop(env: Env) -> Any:
            out = parts[0](env)
            for p in parts[1:]:
                out = red(out, p(env))
            return out

        return boolop

    def _compare(self, node: ast.Compare) -> Node:
        """A comparison chain ``a < b <= c``, the elementwise ``and`` of its links."""
        left = self._compile(node.left)
        ops = []
        for op_node, comp in zip(node.ops, node.comparators, strict=True):
            op = _CMP.get(type(op_node))
            if op is None:
                raise self._err(f"the comparison {type(op_node).__name__}")
            ops.append((op, self._compile(comp)))

        def compare(env: Env) -> Any:
            a = left(env)
            out = None
            for op, f in ops:
                b = f(env)
                r = op(a, b)
                out = r if out is None else np.logical_and(out, r)
                a = b
            return out

        return compare

    def _ifexp(self, node: ast.IfExp) -> Node:
        """``a if c else b``, elementwise (both branches evaluated)."""
        c, a, b = self._compile(node.test), self._compile(node.body), self._compile(node.orelse)
        return lambda env: np.where(c(env), a(env), b(env))

    def _call(self, node: ast.Call) -> Node:
        """A call of a whitelisted function by name, positional arguments only."""
        if not isinstance(node.func, ast.Name):
            raise self._err("calling an attribute or computed function")
        name = node.func.id
        if name not in FUNCTIONS:
            raise self._err(f"the function {name!r}")
        if node.keywords:
            raise self._err("keyword arguments")
        want = ARITY.get(name, 1)
        if len(node.args) != want:
            s = "" if want == 1 else "s"
            raise ExpressionError(
                f"{self.where}: {name}() takes {want} argument{s}, "
                f"got {len(node.args)} in {self.text!r}"
            )
        fn = FUNCTIONS[name]
        args = [self._compile(a) for a in node.args]
        return lambda env: fn(*(a(env) for a in args))

    # -- evaluation ----------------------------------------------------------
    def __call__(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Evaluate at points ``x`` (shape ``(n, gdim)`` or ``(n, 3)``) and time ``t``.

        Returns
        -------
        numpy.ndarray
            Shape ``(n,)``, float64.
        """
        x = np.asarray(x, dtype=float)
        n = x.shape[0]
        env: Env = {"t": float(t)}
        for i, name in enumerate(("x", "y", "z")):
            env[name] = x[:, i] if x.shape[1] > i else np.zeros(n)
        with np.errstate(all="ignore"):
            try:
                val = self._real(self._fn(env))
            except _EVAL_ERRORS as exc:
                raise self._eval_error(exc) from None
        return np.broadcast_to(val, (n,)).copy()

    def value(self) -> float:
        """The value of a constant expression (no x, y, z, t)."""
        if not self.constant:
            raise ExpressionError(f"{self.where}: expected a constant, got {self.text!r}")
        try:
            return float(self._real(self._fn({})))
        except _EVAL_ERRORS as exc:
            raise self._eval_error(exc) from None

    def _real(self, val: Any) -> np.ndarray:
        """``val`` as a float array; a complex value (``x + (-1)**0.5``) raises TypeError."""
        if np.iscomplexobj(val):
            raise TypeError("a complex number, not a real one")
        return np.asarray(val, dtype=float)

    def _eval_error(self, exc: Exception) -> ExpressionError:
        """The :class:`ExpressionError` of an evaluation that raised ``exc``."""
        return ExpressionError(f"{self.where}: {self.text!r} cannot be evaluated ({exc})")

    def __repr__(self) -> str:
        return f"Expression({self.text!r})"


#: The compiler of each whitelisted syntax node type.
_COMPILERS: dict[type[ast.AST], Callable[[Expression, Any], Node]] = {
    ast.Constant: Expression._constant,
    ast.Name: Expression._name,
    ast.BinOp: Expression._binop,
    ast.UnaryOp: Expression._unaryop,
    ast.BoolOp: Expression._boolop,
    ast.Compare: Expression._compare,
    ast.IfExp: Expression._ifexp,
    ast.Call: Expression._call,
}
