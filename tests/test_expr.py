"""Validity rules (bridge/expr.py): what each construct means, which names a rule reads, the exact
error messages, and properties on random rules and random text (hypothesis)."""

from __future__ import annotations

import math
import operator
from collections.abc import Callable, Mapping
from typing import Any

import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from bridge.errors import BridgeError
from bridge.profile.expr import MAX_DEPTH, MAX_LENGTH, Expression, ExpressionError, parse

VALUES: dict[str, float] = {
    "Valid": 1, "ProbExist": 85, "LongDist": 120.5, "LatDist": -3.5, "Class": 0, "Status": 2,
    "Radar.Speed": 12.0,
}


# --- what rules mean ------------------------------------------------------------------------------

@pytest.mark.parametrize(("rule", "expected"), [
    # the rules of a vehicle profile
    ("Valid == 1 and ProbExist > 70", True),
    ("Valid == 1 and ProbExist > 90", False),
    ("LongDist < 150 and (Class != 0 or ProbExist >= 90)", False),
    ("LongDist < 150 and (Class == 0 or ProbExist >= 90)", True),
    ("abs(LatDist) < 20", True),
    ("Status in (1, 2)", True),
    ("Status not in (1, 2)", False),
    ("Status in (-2, 2.0, 7)", True),
    ("LatDist in (-3.5)", True),
    ("Valid in (true)", True),
    ("Radar.Speed > 10", True),
    ("Valid == 1\n  and ProbExist > 70", True),  # TOML multi-line strings are fine
    # literals
    ("42", 42),
    ("0.5", 0.5),
    (".5 + 0.5", 1.0),
    ("5.", 5.0),
    ("1e3", 1000.0),
    ("2.5E-1", 0.25),
    ("true", True),
    ("false", False),
    # arithmetic and its precedence: unary minus > * / > + -, left to right
    ("1 + 2 * 3", 7),
    ("(1 + 2) * 3", 9),
    ("10 - 4 - 3", 3),
    ("8 / 4 / 2", 1.0),
    ("7 / 2", 3.5),
    ("-2 * 3", -6),
    ("2 * -3", -6),
    ("--3", 3),
    ("-LatDist", 3.5),
    ("LongDist - 20.5 * 2", 79.5),
    # booleans count as 1 and 0
    ("true + true", 2),
    ("Valid == true", True),
    ("Valid * 10", 10),
    # comparisons, and chains of them
    ("ProbExist >= 85", True),
    ("ProbExist > 85", False),
    ("ProbExist <= 85", True),
    ("ProbExist != 85.0", False),
    ("0 < LongDist < 200", True),
    ("0 < LongDist < 100", False),
    ("5 > LatDist > -5 >= -10", True),
    ("1 < 2 == true", False),  # 1 < 2 and 2 == true: a chain, not (1 < 2) == true
    ("(1 < 2) == true", True),
    ("1 + 1 == 2", True),  # comparison binds looser than arithmetic
    # and, or, not: or < and < not < comparison; they give bools
    ("true or false and false", True),
    ("(true or false) and false", False),
    ("not true or true", True),
    ("not (true or true)", False),
    ("not Valid == 0", True),  # not (Valid == 0)
    ("not not Valid", True),
    ("LongDist and Class", False),
    ("LongDist or Class", True),
    ("Class or LongDist", True),
    ("LongDist and Valid and ProbExist and Status", True),
    # functions
    ("abs(LatDist)", 3.5),
    ("abs(-2) + max(1, 2) * min(3, 4)", 8),
    ("min(LongDist, 100, 150)", 100),
    ("max(LatDist, -10)", -3.5),
    ("max(Class, Valid, ProbExist, Status)", 85),
    ("ABS", 99),  # keywords and functions are lower case: ABS is a signal
    # values computed from several signals (a vehicle profile's mapped fields)
    ("(LongDist + LatDist) / 2", 58.5),
    ("if(Class == 0, LongDist, LatDist)", 120.5),
    ("if(Valid, 1, 1 / 0)", 1),  # only the branch taken is evaluated
    ("cos(0) + sin(0) + tan(0)", 1.0),
    ("if(LongDist > 100, tan(0.5), 0)", math.tan(0.5)),
])
def test_rule_examples(rule: str, expected: float) -> None:
    result = parse(rule)({**VALUES, "ABS": 99})
    assert result == expected
    assert type(result) is type(expected)


def test_none_is_no_value_as_a_missing_signal_is() -> None:
    # A distance whose zero means "no object": no value, and no error either.
    distance = parse("if(Dist == 0, none, Dist)")
    assert distance.value({"Dist": 42.5}) == 42.5
    assert distance.value({"Dist": 0}) is None
    with pytest.raises(KeyError):
        distance({"Dist": 0})
    assert distance.test({"Dist": 0}) is False
    assert distance.judge({"Dist": 0}) == (False, "")
    assert distance.names == frozenset({"Dist"})
    assert parse("none").value({}) is None


def test_value_is_a_finite_float_or_none_when_it_cannot_be_computed() -> None:
    mean = parse("(FL + FR + RL + RR) / 4")
    wheels = {"FL": 10, "FR": 11, "RL": 12, "RR": 13}
    assert mean.value(wheels) == 11.5
    assert type(parse("FL").value(wheels)) is float
    assert parse("FL > 5").value(wheels) == 1.0  # a bool is 1 or 0
    assert mean.value({"FL": 10, "FR": 11, "RL": 12}) is None  # a signal missing
    assert parse("FL / (FR - 11)").value(wheels) is None  # division by zero
    assert parse("FL * 1e308 * 10").value(wheels) is None  # inf
    assert parse("FL - FL").value({"FL": math.inf}) is None  # NaN
    assert parse("sin(FL)").value({"FL": math.inf}) is None  # math domain error
    assert parse("FL").value({"FL": "moving"}) is None  # type: ignore[dict-item]


def test_names_know_the_column_they_are_first_read_at() -> None:
    rule = parse("(Steering.ANGLE + FRACTION) * 0.5 + FRACTION")
    assert rule.columns == {"Steering.ANGLE": 2, "FRACTION": 19}


def test_and_or_stop_as_soon_as_the_answer_is_known() -> None:
    rule = parse("Class != 0 and 10 / Class > 2")
    assert rule(VALUES) is False  # never divides by zero
    assert parse("Valid == 1 or Missing > 0")(VALUES) is True
    assert parse("0 > Class > 1 / 0")(VALUES) is False  # so do chains


def test_names_are_exactly_the_signals_read() -> None:
    rule = parse("Valid == 1 and (Radar.Speed > ProbExist or abs(LatDist) < min(LongDist, 3))"
                 " and Valid in (1, 2)")
    assert rule.names == frozenset({"Valid", "Radar.Speed", "ProbExist", "LatDist", "LongDist"})
    assert parse("1 < 2 and true or not false").names == frozenset()
    assert parse("max(a, b) > abs(c)").names == frozenset({"a", "b", "c"})


def test_expressions_compare_by_text() -> None:
    rule = parse("Valid == 1")
    assert rule == parse("Valid == 1")
    assert rule.text == "Valid == 1"
    assert repr(rule) == "Expression(text='Valid == 1', names=frozenset({'Valid'}))"


# --- evaluation errors ----------------------------------------------------------------------------

def test_a_missing_name_raises_key_error_but_test_is_false() -> None:
    rule = parse("Valid == 1 and ProbExist > 70")
    with pytest.raises(KeyError, match="ProbExist"):
        rule({"Valid": 1})
    assert rule.test({"Valid": 1}) is False
    assert rule.test({}) is False
    assert rule.test(VALUES) is True


def test_division_by_zero_raises_but_test_is_false() -> None:
    rule = parse("LongDist / Class > 1")
    with pytest.raises(ZeroDivisionError):
        rule(VALUES)
    assert rule.test(VALUES) is False
    assert rule.test({**VALUES, "Class": 2}) is True
    constant = parse("1 / 0 > 0")  # parses; fails only when evaluated, like any other rule
    assert constant.test({}) is False
    assert parse("sin(1e999) > 0").test({}) is False  # math domain error: likewise


def test_test_is_false_for_values_that_are_not_numbers() -> None:
    assert parse("Status > 1").test({"Status": "moving"}) is False  # type: ignore[dict-item]


def test_test_gives_the_truth_of_numbers() -> None:
    assert parse("LongDist").test(VALUES) is True
    assert parse("Class").test(VALUES) is False


# --- parse errors: one line, the rule, the column, what was expected -----------------------------

@pytest.mark.parametrize(("rule", "message"), [
    ("", "rule '': column 1: the rule is empty"),
    ("   ", "rule '   ': column 1: the rule is empty"),
    ("Valid == ", "rule 'Valid == ': column 10: expected a value, found end of rule"),
    ("1 +", "rule '1 +': column 4: expected a value, found end of rule"),
    ("()", "rule '()': column 2: expected a value, found ')'"),
    ("x ** 2", "rule 'x ** 2': column 4: expected a value, found '*'"),
    # trailing input
    ("Valid == 1 2",
     "rule 'Valid == 1 2': column 12: expected an operator or end of rule, found '2'"),
    ("Valid == 1 AND x",
     "rule 'Valid == 1 AND x': column 12: expected an operator or end of rule, found 'AND' "
     "(keywords are lower case: 'and')"),
    # characters that make no token
    ("Valid # 1", "rule 'Valid # 1': column 7: unexpected character '#'"),
    ("x == 'a'", "rule 'x == 'a'': column 6: unexpected character \"'\""),
    ("Dist_m < 5 µs", "rule 'Dist_m < 5 µs': column 12: unexpected character 'µ'"),
    ("x\x00 > 1", "rule 'x  > 1': column 2: unexpected character '\\x00'"),
    ("a && b", "rule 'a && b': column 3: use 'and' instead of '&&'"),
    ("a || b", "rule 'a || b': column 3: use 'or' instead of '||'"),
    ("a & b", "rule 'a & b': column 3: use 'and' instead of '&'"),
    ("a | b", "rule 'a | b': column 3: use 'or' instead of '|'"),
    ("!Valid", "rule '!Valid': column 1: use 'not' instead of '!'"),
    ("Valid = 1", "rule 'Valid = 1': column 7: use '==' to compare, not '='"),
    ("a => 1", "rule 'a => 1': column 3: use '>=' instead of '=>'"),
    ("a =< 1", "rule 'a =< 1': column 3: use '<=' instead of '=<'"),
    ("a <> 1", "rule 'a <> 1': column 3: use '!=' instead of '<>'"),
    ("1e > x", "rule '1e > x': column 1: malformed number '1e'"),
    ("x == 0x10", "rule 'x == 0x10': column 6: malformed number '0x10'"),
    ("x == 1.2.3", "rule 'x == 1.2.3': column 6: malformed number '1.2.3'"),
    ("A.b.c > 1", "rule 'A.b.c > 1': column 1: a signal name has at most one dot, found 'A.b.c'"),
    ("A. > 1", "rule 'A. > 1': column 2: expected a signal name after '.'"),
    # the leftmost problem is reported
    ("Valid == ) && x", "rule 'Valid == ) && x': column 10: expected a value, found ')'"),
    ("Valid == 1 && x = 2", "rule 'Valid == 1 && x = 2': column 12: use 'and' instead of '&&'"),
    # functions
    ("foo(x)",
     "rule 'foo(x)': column 1: unknown function 'foo'; known: abs, cos, if, max, min, sin, tan"),
    ("x > 1 and Radar.abs(x)",
     "rule 'x > 1 and Radar.abs(x)': column 11: unknown function 'Radar.abs'; "
     "known: abs, cos, if, max, min, sin, tan"),
    ("__import__('os')",
     "rule '__import__('os')': column 1: unknown function '__import__'; "
     "known: abs, cos, if, max, min, sin, tan"),
    ("abs(x, y)", "rule 'abs(x, y)': column 1: abs() takes exactly 1 argument, found 2"),
    ("abs()", "rule 'abs()': column 1: abs() takes exactly 1 argument, found 0"),
    ("1 + min(x)", "rule '1 + min(x)': column 5: min() takes at least 2 arguments, found 1"),
    ("if(x, 1)", "rule 'if(x, 1)': column 1: if() takes exactly 3 arguments, found 2"),
    ("tan(x, 1)", "rule 'tan(x, 1)': column 1: tan() takes exactly 1 argument, found 2"),
    ("x in (1, none)",
     "rule 'x in (1, none)': column 10: expected a number, true or false, found 'none'"),
    # parentheses
    ("(a < 1",
     "rule '(a < 1': column 7: expected ')' to close the '(' at column 1, found end of rule"),
    ("(a < 1 b", "rule '(a < 1 b': column 8: expected ')' to close the '(' at column 1, found 'b'"),
    ("a < 1)", "rule 'a < 1)': column 6: found ')' with no '(' to close"),
    ("(a < 1))", "rule '(a < 1))': column 8: found ')' with no '(' to close"),
    ("max(x, 1",
     "rule 'max(x, 1': column 9: expected ',' or ')' to close the '(' at column 4, "
     "found end of rule"),
    # in
    ("x in 1", "rule 'x in 1': column 6: expected '(' after 'in', found '1'"),
    ("x in (1, y)", "rule 'x in (1, y)': column 10: expected a number, true or false, found 'y'"),
    ("x in ()", "rule 'x in ()': column 7: expected a number, true or false, found ')'"),
    ("x in (1 2)",
     "rule 'x in (1 2)': column 9: expected ',' or ')' to close the '(' at column 6, found '2'"),
    ("0 < x in (1, 2)",
     "rule '0 < x in (1, 2)': column 7: a membership test cannot be part of a chain of "
     "comparisons; use parentheses"),
    ("x not in (1, 2) == false",
     "rule 'x not in (1, 2) == false': column 17: a membership test cannot be part of a chain of "
     "comparisons; use parentheses"),
    # a rule on several lines is shown on one, each character where the column says
    ("Valid == 1 and\n  ProbExist >",
     "rule 'Valid == 1 and   ProbExist >': column 29: expected a value, found end of rule"),
])
def test_error_messages(rule: str, message: str) -> None:
    with pytest.raises(ExpressionError) as caught:
        parse(rule)
    assert str(caught.value) == message


def test_an_expression_error_is_a_bridge_error_with_its_parts() -> None:
    with pytest.raises(BridgeError) as caught:
        parse("Valid == ")
    error = caught.value
    assert isinstance(error, ExpressionError)
    assert (error.text, error.column, error.reason) == ("Valid == ", 10,
                                                        "expected a value, found end of rule")


def test_a_rule_has_at_most_1000_characters() -> None:
    assert MAX_LENGTH == 1000
    longest = "ProbExist > 70".ljust(MAX_LENGTH)
    assert parse(longest).test(VALUES)
    with pytest.raises(ExpressionError) as caught:
        parse(longest + " ")
    assert str(caught.value) == (
        f"rule '{'ProbExist > 70'.ljust(40)}...': column 1001: "
        "a rule may have at most 1000 characters, this one has 1001")


@pytest.mark.parametrize(("opening", "closing", "levels_each", "column"), [
    ("(", ")", 1, 51),
    ("-", "", 1, 51),
    ("not ", "", 1, 201),
    ("abs(", ")", 1, 204),  # the 51st '('
    ("-(", ")", 2, 51),  # the 26th '-'
])
def test_a_rule_nests_at_most_50_levels_deep(opening: str, closing: str, levels_each: int,
                                            column: int) -> None:
    assert MAX_DEPTH == 50
    n = MAX_DEPTH // levels_each
    deepest = parse(opening * n + "Valid" + closing * n)
    assert deepest.names == frozenset({"Valid"})
    assert isinstance(deepest(VALUES), int)
    too_deep = opening * (n + 1) + "Valid" + closing * (n + 1)
    with pytest.raises(ExpressionError) as caught:
        parse(too_deep)
    assert str(caught.value) == (
        f"rule '{too_deep}': column {column}: the rule nests more than 50 levels deep")


# --- properties -----------------------------------------------------------------------------------
# Random rules are trees of tuples, rendered with as few parentheses as the precedence allows, and
# evaluated by a plain Python reference evaluator over the same tree.

Tree = tuple[Any, ...]
NAMES = ("a", "b", "Msg.c")
ARITH: dict[str, Callable[[Any, Any], Any]] = {
    "+": operator.add, "-": operator.sub, "*": operator.mul, "/": operator.truediv}
COMPARE: dict[str, Callable[[Any, Any], Any]] = {
    "==": operator.eq, "!=": operator.ne, "<": operator.lt, "<=": operator.le, ">": operator.gt,
    ">=": operator.ge}
FUNCTIONS: dict[str, Callable[..., Any]] = {"abs": abs, "min": min, "max": max}

literals = st.one_of(st.integers(0, 10**6),
                     st.floats(min_value=0.0, allow_nan=False, allow_infinity=False).map(abs),
                     st.booleans())
signed = st.one_of(st.integers(-10**6, 10**6), st.floats(allow_nan=False, allow_infinity=False))
leaves = st.one_of(literals.map(lambda v: ("num", v)), st.sampled_from(NAMES).map(
    lambda n: ("name", n)))


def _extend(children: st.SearchStrategy[Tree]) -> st.SearchStrategy[Tree]:
    return st.one_of(
        st.tuples(st.just("neg"), children),
        st.tuples(st.just("not"), children),
        st.tuples(st.just("arith"), st.sampled_from(sorted(ARITH)), children, children),
        st.tuples(st.just("cmp"), children,
                  st.lists(st.tuples(st.sampled_from(sorted(COMPARE)), children), min_size=1,
                           max_size=3).map(tuple)),
        st.tuples(st.just("bool"), st.sampled_from(["and", "or"]), children, children),
        st.tuples(st.just("in"), children,
                  st.lists(st.one_of(signed, st.booleans()), min_size=1, max_size=4).map(tuple),
                  st.booleans()),
        st.tuples(st.just("call"), st.just("abs"), children.map(lambda x: (x,))),
        st.tuples(st.just("call"), st.sampled_from(["min", "max"]),
                  st.lists(children, min_size=2, max_size=4).map(tuple)),
    )


trees = st.recursive(leaves, _extend, max_leaves=12)
values = st.fixed_dictionaries({name: st.one_of(signed, st.booleans()) for name in NAMES})


def number(value: float) -> str:
    return str(value).lower() if isinstance(value, bool) else repr(value)


def render(tree: Tree) -> tuple[str, int]:
    """The rule's text and its precedence: 1 or, 2 and, 3 not, 4 comparison, 5 + -, 6 * /,
    7 unary minus, 8 atom."""
    def wrap(sub: Tree, level: int) -> str:
        text, own = render(sub)
        return text if own >= level else f"({text})"

    kind = tree[0]
    if kind == "num":
        return number(tree[1]), 8
    if kind == "name":
        return tree[1], 8
    if kind == "neg":
        return "-" + wrap(tree[1], 7), 7
    if kind == "not":
        return "not " + wrap(tree[1], 3), 3
    if kind == "arith":
        _, op, a, b = tree
        level = 5 if op in "+-" else 6
        return f"{wrap(a, level)} {op} {wrap(b, level + 1)}", level
    if kind == "cmp":
        _, first, rest = tree
        return wrap(first, 5) + "".join(f" {op} {wrap(x, 5)}" for op, x in rest), 4
    if kind == "bool":
        _, op, a, b = tree
        level = 1 if op == "or" else 2
        return f"{wrap(a, level)} {op} {wrap(b, level + 1)}", level
    if kind == "in":
        _, x, choices, negated = tree
        listed = ", ".join(number(c) for c in choices)
        return f"{wrap(x, 5)} {'not in' if negated else 'in'} ({listed})", 4
    _, function, args = tree
    return f"{function}({', '.join(render(arg)[0] for arg in args)})", 8


def reference(tree: Tree, values: Mapping[str, float]) -> Any:
    """What the rule means, in plain Python."""
    kind = tree[0]
    if kind == "num":
        return tree[1]
    if kind == "name":
        return values[tree[1]]
    if kind == "neg":
        return -reference(tree[1], values)
    if kind == "not":
        return not reference(tree[1], values)
    if kind == "arith":
        _, op, a, b = tree
        return ARITH[op](reference(a, values), reference(b, values))
    if kind == "cmp":
        _, first, rest = tree
        left = reference(first, values)
        for op, x in rest:
            right = reference(x, values)
            if not COMPARE[op](left, right):
                return False
            left = right
        return True
    if kind == "bool":
        _, op, a, b = tree
        if op == "and":
            return bool(reference(a, values)) and bool(reference(b, values))
        return bool(reference(a, values)) or bool(reference(b, values))
    if kind == "in":
        _, x, choices, negated = tree
        return (reference(x, values) in choices) != negated
    _, function, args = tree
    return FUNCTIONS[function](*(reference(arg, values) for arg in args))


def children(tree: Tree) -> list[Tree]:
    kind = tree[0]
    if kind in ("neg", "not", "in"):
        return [tree[1]]
    if kind in ("arith", "bool"):
        return [tree[2], tree[3]]
    if kind == "cmp":
        return [tree[1], *(x for _, x in tree[2])]
    if kind == "call":
        return list(tree[2])
    return []


def depth(tree: Tree) -> int:
    return 1 + max((depth(child) for child in children(tree)), default=0)


def tree_names(tree: Tree) -> set[str]:
    if tree[0] == "name":
        return {tree[1]}
    return set().union(*(tree_names(child) for child in children(tree)))


def outcome(evaluate: Callable[[], Any]) -> tuple[str, Any]:
    try:
        result = evaluate()
    except ArithmeticError as error:
        return "error", type(error)
    if isinstance(result, float) and math.isnan(result):
        return "nan", float
    return "value", (type(result), result)


@given(trees, values)
def test_random_rules_mean_what_python_says(tree: Tree, values: dict[str, float]) -> None:
    assume(depth(tree) <= 20)
    text, _ = render(tree)
    assume(len(text) <= MAX_LENGTH)
    rule = parse(text)
    assert outcome(lambda: rule(values)) == outcome(lambda: reference(tree, values)), text
    assert rule.names == tree_names(tree)


@given(st.text(max_size=300))
def test_random_text_parses_or_raises_an_expression_error(text: str) -> None:
    check_any_text(text)


FRAGMENTS = ["a", "Msg.b", "Msg.", "1", "2.5", ".5", "1e3", "1e", "(", ")", ",", "==", "!=", "<",
             "<=", "=", "!", "&&", "|", "+", "-", "*", "/", "and", "or", "not", "in", "true",
             "false", "abs", "min", "max", "if", "none", "tan", "foo", " ", "\n", "é", "'", "#",
             "AND"]


@given(st.lists(st.sampled_from(FRAGMENTS), max_size=80).map("".join))
def test_random_token_soup_parses_or_raises_an_expression_error(text: str) -> None:
    check_any_text(text)


def check_any_text(text: str) -> None:
    try:
        rule = parse(text)
    except ExpressionError as error:
        assert "\n" not in str(error)
        assert 1 <= error.column <= len(text) + 1
        return
    assert isinstance(rule, Expression)
    assert rule.test({}) in (True, False)
    assert rule.test(dict.fromkeys(rule.names, 0)) in (True, False)
    assert rule.test(dict.fromkeys(rule.names, 1.5)) in (True, False)
