"""The restricted expression evaluator: vectorised values and refusals."""

import numpy as np
import pytest

from pfem2x.expr import Expression, ExpressionError

X = np.array([[0.0, 1.0], [0.5, -1.0], [1.0, 2.0]])


def test_values_match_numpy():
    e = Expression("0.1*d*cos(2*pi*x/d) + y**2 - t", {"d": 2.0})
    want = 0.1 * 2.0 * np.cos(2 * np.pi * X[:, 0] / 2.0) + X[:, 1] ** 2 - 0.5
    assert np.allclose(e(X, t=0.5), want)


def test_conditionals_and_comparisons_are_elementwise():
    e = Expression("1 if x < 0.75 and y > 0 else -1")
    assert e(X).tolist() == [1.0, -1.0, -1.0]
    chained = Expression("0 < x <= 0.5")
    assert chained(X).tolist() == [0.0, 1.0, 0.0]


def test_constant_expressions():
    e = Expression(3)
    assert e.constant and e.value() == 3.0
    assert e(X).shape == (3,)
    assert not Expression("x").constant


@pytest.mark.parametrize(
    "text",
    [
        "__import__('os').system('true')",
        "x.__class__",
        "().__class__.__bases__",
        "open('f')",
        "eval('1')",
        "lambda: 1",
        "[x for x in y]",
        "params['d']",
        "__builtins__",
        "'abc'",
        "sin",
        "exp(x, out=y)",
        "x +",
    ],
)
def test_refused(text):
    with pytest.raises(ExpressionError):
        Expression(text, {"d": 1.0}, where="transport.initial")


def test_unknown_name_lists_known_params():
    with pytest.raises(ExpressionError, match="unknown name 'omega'.*kappa"):
        Expression("omega*t", {"kappa": 1.0})


@pytest.mark.parametrize(
    "text, needle",
    [
        ("sin(1, 2)", "sin() takes 1 argument, got 2"),
        ("sin()", "sin() takes 1 argument, got 0"),
        ("hypot(x)", "hypot() takes 2 arguments, got 1"),
        ("min(x)", "min() takes 2 arguments, got 1"),
        ("where(x > 0, 1)", "where() takes 3 arguments, got 2"),
        ("exp(x, y)", "exp() takes 1 argument, got 2"),
    ],
)
def test_wrong_argument_count_is_refused_when_compiled(text, needle):
    with pytest.raises(ExpressionError, match=r"^transport\.initial: ") as info:
        Expression(text, where="transport.initial")
    assert needle in str(info.value)


@pytest.mark.parametrize("text", ["9.0**9**9", "x + 9.0**9**9", "1/(t - 0.5)", "x + (-1)**0.5"])
def test_evaluation_failure_names_the_key(text):
    e = Expression(text, where="transport.source")
    with pytest.raises(ExpressionError, match=r"^transport\.source: .* cannot be evaluated"):
        e(X, t=0.5)
    if e.constant:
        with pytest.raises(ExpressionError, match=r"^transport\.source: "):
            e.value()
