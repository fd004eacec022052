"""Validity rules and computed values: a small, safe expression language over the signals of
decoded CAN messages.

A vehicle profile gives a group of objects a rule such as ``Valid == 1 and ProbExist > 70``, and
may compute a mapped value from several signals, such as ``(Steering.ANGLE + Steering.FRACTION) *
0.01745329`` or ``if(Dist == 0, none, Dist)``;
:func:`parse` reads it once (a tokenizer and a recursive-descent parser of our own, never Python's
``eval``) and compiles it into nested closures, and the resulting :class:`Expression` is then
evaluated on every decoded message, a mapping of signal name to number::

    rule = parse("LongDist < 150 and (Class != 0 or ProbExist >= 90)")
    rule.names                                   # frozenset({'LongDist', 'Class', 'ProbExist'})
    rule.test({"LongDist": 80, "Class": 0, "ProbExist": 95})           # True
    parse("(FL + FR + RL + RR) / 4").value({"FL": 10, "FR": 11, "RL": 12, "RR": 13})   # 11.5

Grammar
-------

From the loosest to the tightest binding (``{ }`` repeats, ``[ ]`` is optional)::

    rule        = or
    or          = and { "or" and }
    and         = not { "and" not }
    not         = "not" not | comparison
    comparison  = sum [ { compare-op sum } | [ "not" ] "in" "(" literal { "," literal } ")" ]
    compare-op  = "==" | "!=" | "<" | "<=" | ">" | ">="
    sum         = product { ( "+" | "-" ) product }
    product     = unary { ( "*" | "/" ) unary }
    unary       = "-" unary | atom
    atom        = number | "true" | "false" | "none" | name
                | function "(" rule { "," rule } ")" | "(" rule ")"
    literal     = [ "-" ] number | "true" | "false"
    function    = "abs" | "cos" | "if" | "max" | "min" | "sin" | "tan"
    name        = word [ "." word ]          (a signal, or Message.Signal)
    word        = [A-Za-z_][A-Za-z0-9_]*     (except the keywords and, or, not, in, true, false,
                                              none)
    number      = 12 | 0.5 | .5 | 5. | 1e3 | 2.5E-2

- A name is looked up in the values given at evaluation time, dotted names (``Message.Signal``)
  as the whole dotted string.
- ``+ - * /`` are Python's arithmetic (``/`` always divides exactly: ``7 / 2`` is ``3.5``); ``-x``
  negates. ``true`` and ``false`` count as 1 and 0 in arithmetic.
- Comparisons compare numbers as Python does (``1 == 1.0``). A chain ``0 < x <= 5`` means
  ``0 < x and x <= 5``, reading ``x`` once. ``x in (1, 2, 3)`` is true when ``x`` equals one of the
  numbers; ``x not in (...)`` is its negation; a membership test cannot be part of a chain.
- ``and``, ``or`` and ``not`` give ``true`` or ``false`` and stop as soon as the answer is known
  (``x != 0 and 10 / x > 2`` never divides by zero). Any other value is true when it is not zero.
- ``abs(x)`` is the absolute value; ``min(a, b, ...)`` and ``max(a, b, ...)`` take two or more;
  ``sin(x)``, ``cos(x)`` and ``tan(x)`` take radians (``tan(Angle * 0.01745329)`` for degrees).
- ``if(condition, then, otherwise)`` is ``then`` where the condition is true (not zero), else
  ``otherwise``; only the branch taken is evaluated (``if(x != 0, 10 / x, 0)`` never divides by
  zero).
- ``none`` is no value: evaluating it is as if a signal were missing (:class:`KeyError`), so
  ``if(Dist == 0, none, Dist)`` reads a distance whose zero means "no object" as missing.
- Keywords are lower case; spaces, tabs and line breaks between tokens are ignored.
- ``&&``, ``||``, ``!`` and ``=`` are errors that name the right word (``and``, ``or``, ``not``,
  ``==``). A rule has at most 1,000 characters and nests at most 50 levels deep (parentheses,
  function calls, ``not`` and unary ``-`` each count as one level).

Errors
------

Every problem is an :class:`ExpressionError`, one line naming the rule, the column (1-based) and
what was expected, e.g. ``rule 'Valid == ': column 10: expected a value, found end of rule``.

Evaluation
----------

``rule(values)`` returns the value (a number or a bool) and raises :class:`KeyError` for a name
missing from ``values`` (or ``none``) and :class:`ZeroDivisionError` for a division by zero.
``rule.value(values)``, for a computed value, returns it as a finite float, or None when it cannot
be computed: a missing name, ``none``, an arithmetic error, a value that is not a number, or a
result that is infinite or NaN.
``rule.test(values)``, meant for the hot path, returns a bool and never raises for a missing name,
an arithmetic error or a value that is not a number: such a rule is simply not satisfied.
``rule.judge(values)`` tells those apart: ``(holds, why)``, where ``why`` is ``""`` when the rule
could be evaluated (a missing name counts as not satisfied: the signal has not come yet) and names
the error when it could not (``"ZeroDivisionError: division by zero"``, a value that is not a
number); ``holds`` is then False. The world counts such errors (:mod:`bridge.world.observe`).
``rule.columns`` gives the column (1-based) where each name is first read, for errors that name
it (a signal that is not in the databases).
"""

from __future__ import annotations

import math
import operator
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import NoReturn, TypeAlias

from bridge.errors import BridgeError

__all__ = ["FUNCTIONS", "MAX_DEPTH", "MAX_LENGTH", "Expression", "ExpressionError", "parse"]

#: The longest rule, in characters.
MAX_LENGTH = 1000
#: The deepest nesting of parentheses, function calls, ``not`` and unary ``-``.
MAX_DEPTH = 50
#: The functions a rule may call.
FUNCTIONS = ("abs", "cos", "if", "max", "min", "sin", "tan")
#: How many arguments each function takes: exactly (an int) or at least (a str "2+").
_ARITY = {"abs": 1, "cos": 1, "sin": 1, "tan": 1, "if": 3, "max": 2, "min": 2}
_TRIG: dict[str, Callable[[float], float]] = {"cos": math.cos, "sin": math.sin, "tan": math.tan}

Value: TypeAlias = float | bool  # ints are floats to the type checker, and bools are ints
Values: TypeAlias = Mapping[str, float | int]
Fn: TypeAlias = Callable[[Values], Value]

#: What :meth:`Expression.test` treats as "not satisfied" rather than as a bug.
_EVALUATION_ERRORS = (LookupError, ArithmeticError, TypeError, ValueError)


class ExpressionError(BridgeError):
    """A rule that does not parse: names the rule, the column (1-based) and what was expected."""

    def __init__(self, text: str, column: int, reason: str) -> None:
        self.text = text
        self.column = column
        self.reason = reason
        super().__init__(f"rule '{_display(text)}': column {column}: {reason}")


def _display(text: str) -> str:
    """The rule on one line, each character in its place so that columns still point at it."""
    if len(text) > MAX_LENGTH:
        text = text[:40] + "..."
    return "".join(c if c.isprintable() else " " for c in text)


@dataclass(frozen=True, slots=True)
class Expression:
    """A parsed rule: call it for its value, or :meth:`test` it for a bool."""

    #: The rule as written.
    text: str
    #: Every signal name the rule reads (to check against a DBC).
    names: frozenset[str]
    _fn: Fn = field(repr=False, compare=False)
    #: The column (1-based) where each name is first read.
    columns: Mapping[str, int] = field(default_factory=dict, repr=False, compare=False)

    def __call__(self, values: Values) -> Value:
        """The rule's value; :class:`KeyError` for a missing name, ZeroDivisionError, ..."""
        return self._fn(values)

    def test(self, values: Values) -> bool:
        """Whether the rule holds; False when a name is missing or the arithmetic fails."""
        try:
            return bool(self._fn(values))
        except _EVALUATION_ERRORS:
            return False

    def value(self, values: Values) -> float | None:
        """The value as a finite float; None when it cannot be computed (a missing name,
        ``none``, an arithmetic error, a value that is not a number, infinity or NaN)."""
        try:
            result = float(self._fn(values))
        except _EVALUATION_ERRORS:
            return None
        return result if math.isfinite(result) else None

    def judge(self, values: Values) -> tuple[bool, str]:
        """Whether the rule holds, and why it could not be evaluated ("" when it could; a missing
        name is "not satisfied", not an error)."""
        try:
            return bool(self._fn(values)), ""
        except LookupError:
            return False, ""
        except _EVALUATION_ERRORS as exc:
            return False, f"{type(exc).__name__}: {exc}"


def parse(text: str) -> Expression:
    """Parse and compile a rule; :class:`ExpressionError` says where and why it is wrong."""
    if len(text) > MAX_LENGTH:
        raise ExpressionError(text, MAX_LENGTH + 1,
                              f"a rule may have at most {MAX_LENGTH} characters, "
                              f"this one has {len(text)}")
    parser = _Parser(text)
    tree = parser.rule()
    return Expression(text, frozenset(parser.names), _as_fn(_compile(tree)), parser.names)


# --- tokens ---------------------------------------------------------------------------------------

_NUMBER = re.compile(r"(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_WORD = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_NAME_TAIL = re.compile(r"[A-Za-z0-9_.]*")
_KEYWORDS = frozenset({"and", "or", "not", "in", "true", "false", "none"})
_OPERATORS = ("==", "!=", "<=", ">=", "<", ">", "+", "-", "*", "/", "(", ")", ",")
_COMPARISONS = frozenset({"==", "!=", "<", "<=", ">", ">="})
#: Operators of other languages, and what to write instead.
_MISTAKES = {
    "&&": "use 'and' instead of '&&'",
    "||": "use 'or' instead of '||'",
    "=>": "use '>=' instead of '=>'",
    "=<": "use '<=' instead of '=<'",
    "<>": "use '!=' instead of '<>'",
    "&": "use 'and' instead of '&'",
    "|": "use 'or' instead of '|'",
    "!": "use 'not' instead of '!'",
    "=": "use '==' to compare, not '='",
}


@dataclass(frozen=True, slots=True)
class _Token:
    kind: str  # "number", "name", "end", "error", a keyword or an operator
    text: str  # as written; for "error", what is wrong
    column: int
    value: Value = 0


def _tail_end(text: str, start: int) -> int:
    """Where the run of name characters and dots from ``start`` ends."""
    m = _NAME_TAIL.match(text, start)
    return m.end() if m else start


def _tokenize(text: str) -> list[_Token]:
    """The tokens of ``text``, ending with an "end" token, or with an "error" token at the first
    character that makes no token (the parser reports it only if it gets there)."""
    tokens: list[_Token] = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        column = i + 1
        if c.isspace():
            i += 1
            continue
        m = _NUMBER.match(text, i)
        if m:
            end = _tail_end(text, m.end())
            if end > m.end():
                return [*tokens, _Token("error", f"malformed number '{text[i:end]}'", column)]
            s = m.group()
            value: Value = float(s) if any(ch in s for ch in ".eE") else int(s)
            tokens.append(_Token("number", s, column, value))
            i = m.end()
            continue
        m = _WORD.match(text, i)
        if m:
            word, i = m.group(), m.end()
            if text.startswith(".", i):
                second = _WORD.match(text, i + 1)
                if second is None:
                    return [*tokens, _Token("error", "expected a signal name after '.'", i + 1)]
                word, i = f"{word}.{second.group()}", second.end()
                if text.startswith(".", i):
                    end = _tail_end(text, i)
                    reason = f"a signal name has at most one dot, found '{text[m.start():end]}'"
                    return [*tokens, _Token("error", reason, column)]
                tokens.append(_Token("name", word, column))
            else:
                tokens.append(_Token(word if word in _KEYWORDS else "name", word, column))
            continue
        pair = text[i:i + 2]
        if pair in _MISTAKES or (c in _MISTAKES and pair not in _OPERATORS):
            return [*tokens, _Token("error", _MISTAKES.get(pair) or _MISTAKES[c], column)]
        op = pair if pair in _OPERATORS else c
        if op not in _OPERATORS:
            return [*tokens, _Token("error", f"unexpected character {c!r}", column)]
        tokens.append(_Token(op, op, column))
        i += len(op)
    tokens.append(_Token("end", "", n + 1))
    return tokens


# --- the tree -------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _Num:
    value: Value


@dataclass(frozen=True, slots=True)
class _Name:
    name: str


@dataclass(frozen=True, slots=True)
class _NoValue:
    """``none``: no value, as a missing signal."""


@dataclass(frozen=True, slots=True)
class _Neg:
    operand: _Node


@dataclass(frozen=True, slots=True)
class _Not:
    operand: _Node


@dataclass(frozen=True, slots=True)
class _Arith:
    """``first op1 x1 op2 x2 ...`` for ``+ -`` or for ``* /``, from left to right."""

    first: _Node
    rest: tuple[tuple[str, _Node], ...]


@dataclass(frozen=True, slots=True)
class _Compare:
    """A chain ``first op1 x1 op2 x2 ...`` meaning ``first op1 x1 and x1 op2 x2 ...``."""

    first: _Node
    rest: tuple[tuple[str, _Node], ...]


@dataclass(frozen=True, slots=True)
class _Member:
    operand: _Node
    choices: tuple[Value, ...]
    negated: bool


@dataclass(frozen=True, slots=True)
class _BoolOp:
    op: str  # "and" | "or"
    operands: tuple[_Node, ...]


@dataclass(frozen=True, slots=True)
class _Call:
    function: str
    args: tuple[_Node, ...]


_Node: TypeAlias = (_Num | _Name | _NoValue | _Neg | _Not | _Arith | _Compare | _Member | _BoolOp
                    | _Call)


# --- the parser -----------------------------------------------------------------------------------


def _found(token: _Token) -> str:
    return "end of rule" if token.kind == "end" else f"'{token.text}'"


class _Parser:
    """Recursive descent over the grammar in the module docstring, one method per level."""

    def __init__(self, text: str) -> None:
        self.text = text
        self.tokens = _tokenize(text)
        self.pos = 0
        self.depth = 0
        #: name -> the column where it is first read
        self.names: dict[str, int] = {}

    def peek(self, ahead: int = 0) -> _Token:
        return self.tokens[min(self.pos + ahead, len(self.tokens) - 1)]

    def advance(self) -> _Token:
        token = self.peek()
        self.pos = min(self.pos + 1, len(self.tokens) - 1)
        return token

    def fail(self, token: _Token, reason: str) -> NoReturn:
        if token.kind == "error":  # the parser got as far as a character that makes no token
            reason = token.text
        raise ExpressionError(self.text, token.column, reason)

    def enter(self, token: _Token) -> None:
        self.depth += 1
        if self.depth > MAX_DEPTH:
            self.fail(token, f"the rule nests more than {MAX_DEPTH} levels deep")

    def close(self, opening: _Token, *, comma: bool = False) -> _Token:
        """The ``,`` (if allowed) or ``)`` that follows, consumed."""
        token = self.advance()
        if token.kind == ")" or (comma and token.kind == ","):
            return token
        expected = "',' or ')'" if comma else "')'"
        self.fail(token, f"expected {expected} to close the '(' at column {opening.column}, "
                         f"found {_found(token)}")

    def rule(self) -> _Node:
        token = self.peek()
        if token.kind == "end":
            self.fail(_Token("end", "", 1), "the rule is empty")
        node = self.or_()
        token = self.peek()
        if token.kind == ")":
            self.fail(token, "found ')' with no '(' to close")
        if token.kind != "end":
            hint = ""
            if token.kind == "name" and token.text.lower() in _KEYWORDS:
                hint = f" (keywords are lower case: '{token.text.lower()}')"
            self.fail(token, f"expected an operator or end of rule, found {_found(token)}{hint}")
        return node

    def or_(self) -> _Node:
        operands = [self.and_()]
        while self.peek().kind == "or":
            self.advance()
            operands.append(self.and_())
        return _BoolOp("or", tuple(operands)) if len(operands) > 1 else operands[0]

    def and_(self) -> _Node:
        operands = [self.not_()]
        while self.peek().kind == "and":
            self.advance()
            operands.append(self.not_())
        return _BoolOp("and", tuple(operands)) if len(operands) > 1 else operands[0]

    def not_(self) -> _Node:
        if self.peek().kind != "not":
            return self.comparison()
        self.enter(self.advance())
        node = _Not(self.not_())
        self.depth -= 1
        return node

    def at_membership(self) -> bool:
        return self.peek().kind == "in" or (self.peek().kind == "not"
                                            and self.peek(1).kind == "in")

    def comparison(self) -> _Node:
        first = self.sum()
        if self.at_membership():
            negated = self.advance().kind == "not"
            if negated:
                self.advance()
            node: _Node = _Member(first, self.choices(), negated)
        elif self.peek().kind in _COMPARISONS:
            rest: list[tuple[str, _Node]] = []
            while self.peek().kind in _COMPARISONS:
                op = self.advance().kind
                rest.append((op, self.sum()))
            node = _Compare(first, tuple(rest))
        else:
            return first
        if self.at_membership() or self.peek().kind in _COMPARISONS:
            self.fail(self.peek(), "a membership test cannot be part of a chain of comparisons; "
                                   "use parentheses")
        return node

    def choices(self) -> tuple[Value, ...]:
        opening = self.advance()
        if opening.kind != "(":
            self.fail(opening, f"expected '(' after 'in', found {_found(opening)}")
        values: list[Value] = []
        while True:
            token = self.advance()
            sign = 1
            if token.kind == "-" and self.peek().kind == "number":
                sign, token = -1, self.advance()
            if token.kind == "number":
                values.append(sign * token.value)
            elif token.kind in ("true", "false"):
                values.append(token.kind == "true")
            else:
                self.fail(token, f"expected a number, true or false, found {_found(token)}")
            if self.close(opening, comma=True).kind == ")":
                return tuple(values)

    def sum(self) -> _Node:
        first = self.product()
        rest: list[tuple[str, _Node]] = []
        while self.peek().kind in ("+", "-"):
            op = self.advance().kind
            rest.append((op, self.product()))
        return _Arith(first, tuple(rest)) if rest else first

    def product(self) -> _Node:
        first = self.unary()
        rest: list[tuple[str, _Node]] = []
        while self.peek().kind in ("*", "/"):
            op = self.advance().kind
            rest.append((op, self.unary()))
        return _Arith(first, tuple(rest)) if rest else first

    def unary(self) -> _Node:
        if self.peek().kind != "-":
            return self.atom()
        self.enter(self.advance())
        node = _Neg(self.unary())
        self.depth -= 1
        return node

    def atom(self) -> _Node:
        token = self.advance()
        if token.kind == "number":
            return _Num(token.value)
        if token.kind in ("true", "false"):
            return _Num(token.kind == "true")
        if token.kind == "none":
            return _NoValue()
        if token.kind == "name" and self.peek().kind == "(":
            return self.call(token)
        if token.kind == "name":
            self.names.setdefault(token.text, token.column)
            return _Name(token.text)
        if token.kind == "(":
            self.enter(token)
            node = self.or_()
            self.close(token)
            self.depth -= 1
            return node
        self.fail(token, f"expected a value, found {_found(token)}")

    def call(self, name: _Token) -> _Node:
        function = name.text
        if function not in FUNCTIONS:
            self.fail(name, f"unknown function '{function}'; known: {', '.join(FUNCTIONS)}")
        opening = self.advance()
        self.enter(opening)
        args: list[_Node] = []
        if self.peek().kind == ")":
            self.advance()
        else:
            args.append(self.or_())
            while self.close(opening, comma=True).kind == ",":
                args.append(self.or_())
        self.depth -= 1
        arity = _ARITY[function]
        if function in ("min", "max") and len(args) < arity:
            self.fail(name, f"{function}() takes at least {arity} arguments, found {len(args)}")
        if function not in ("min", "max") and len(args) != arity:
            plural = "argument" if arity == 1 else "arguments"
            self.fail(name, f"{function}() takes exactly {arity} {plural}, found {len(args)}")
        return _Call(function, tuple(args))


# --- the compiler: the tree becomes nested closures -----------------------------------------------
# Each node compiles to a constant, a plain name lookup or a closure; the common shapes
# (``Name op constant``, two operands) get closures of their own, so that a typical rule costs
# one Python call per comparison. Subtrees without names are computed once, here.


@dataclass(frozen=True, slots=True)
class _Const:
    value: Value


@dataclass(frozen=True, slots=True)
class _Lookup:
    name: str


_Code: TypeAlias = _Const | _Lookup | Fn


def _as_fn(code: _Code) -> Fn:
    if isinstance(code, _Const):
        value = code.value
        return lambda v: value
    if isinstance(code, _Lookup):
        name = code.name
        return lambda v: v[name]
    return code


_OPS: dict[str, Callable[[Value, Value], Value]] = {
    "+": operator.add, "-": operator.sub, "*": operator.mul, "/": operator.truediv,
    "==": operator.eq, "!=": operator.ne, "<": operator.lt, "<=": operator.le,
    ">": operator.gt, ">=": operator.ge,
}
#: ``a op b`` is ``b flipped-op a``.
_FLIPPED = {"==": "==", "!=": "!=", "<": ">", "<=": ">=", ">": "<", ">=": "<="}

# name op constant
_NC: dict[str, Callable[[str, Value], Fn]] = {
    "+": lambda n, c: lambda v: v[n] + c,
    "-": lambda n, c: lambda v: v[n] - c,
    "*": lambda n, c: lambda v: v[n] * c,
    "/": lambda n, c: lambda v: v[n] / c,
    "==": lambda n, c: lambda v: v[n] == c,
    "!=": lambda n, c: lambda v: v[n] != c,
    "<": lambda n, c: lambda v: v[n] < c,
    "<=": lambda n, c: lambda v: v[n] <= c,
    ">": lambda n, c: lambda v: v[n] > c,
    ">=": lambda n, c: lambda v: v[n] >= c,
}
# closure op constant
_FC: dict[str, Callable[[Fn, Value], Fn]] = {
    "+": lambda f, c: lambda v: f(v) + c,
    "-": lambda f, c: lambda v: f(v) - c,
    "*": lambda f, c: lambda v: f(v) * c,
    "/": lambda f, c: lambda v: f(v) / c,
    "==": lambda f, c: lambda v: f(v) == c,
    "!=": lambda f, c: lambda v: f(v) != c,
    "<": lambda f, c: lambda v: f(v) < c,
    "<=": lambda f, c: lambda v: f(v) <= c,
    ">": lambda f, c: lambda v: f(v) > c,
    ">=": lambda f, c: lambda v: f(v) >= c,
}
# constant op closure (arithmetic only: comparisons are flipped)
_CF: dict[str, Callable[[Value, Fn], Fn]] = {
    "+": lambda c, f: lambda v: c + f(v),
    "-": lambda c, f: lambda v: c - f(v),
    "*": lambda c, f: lambda v: c * f(v),
    "/": lambda c, f: lambda v: c / f(v),
}
# closure op closure
_FF: dict[str, Callable[[Fn, Fn], Fn]] = {
    "+": lambda f, g: lambda v: f(v) + g(v),
    "-": lambda f, g: lambda v: f(v) - g(v),
    "*": lambda f, g: lambda v: f(v) * g(v),
    "/": lambda f, g: lambda v: f(v) / g(v),
    "==": lambda f, g: lambda v: f(v) == g(v),
    "!=": lambda f, g: lambda v: f(v) != g(v),
    "<": lambda f, g: lambda v: f(v) < g(v),
    "<=": lambda f, g: lambda v: f(v) <= g(v),
    ">": lambda f, g: lambda v: f(v) > g(v),
    ">=": lambda f, g: lambda v: f(v) >= g(v),
}


def _fold(fn: Fn, *parts: _Code) -> _Code:
    """``fn``, or its value when it reads no name and can be computed now."""
    if all(isinstance(part, _Const) for part in parts):
        try:
            return _Const(fn({}))
        except (ArithmeticError, ValueError):  # 1 / 0, sin(1e999): left to fail at evaluation,
            # where callers expect it
            pass
    return fn


def _binary(op: str, a: _Code, b: _Code) -> _Code:
    if isinstance(a, _Const) and not isinstance(b, _Const):
        if op in _FLIPPED:
            return _binary(_FLIPPED[op], b, a)
        fn = _CF[op](a.value, _as_fn(b))
    elif isinstance(b, _Const):
        fn = _NC[op](a.name, b.value) if isinstance(a, _Lookup) else _FC[op](_as_fn(a), b.value)
    else:
        fn = _FF[op](_as_fn(a), _as_fn(b))
    return _fold(fn, a, b)


def _arith_chain(first: Fn, rest: list[tuple[Callable[[Value, Value], Value], Fn]]) -> Fn:
    def chain(v: Values) -> Value:
        result = first(v)
        for op, f in rest:
            result = op(result, f(v))
        return result
    return chain


def _compare_chain(first: Fn, rest: list[tuple[Callable[[Value, Value], Value], Fn]]) -> Fn:
    def chain(v: Values) -> Value:
        left = first(v)
        for op, f in rest:
            right = f(v)
            if not op(left, right):
                return False
            left = right
        return True
    return chain


def _is_bool(node: _Node) -> bool:
    """Whether the node's value is always a bool."""
    return (isinstance(node, (_Compare, _Member, _Not, _BoolOp))
            or (isinstance(node, _Num) and isinstance(node.value, bool)))


def _all(fs: list[Fn]) -> Fn:
    def all_(v: Values) -> Value:
        return all(f(v) for f in fs)
    return all_


def _any(fs: list[Fn]) -> Fn:
    def any_(v: Values) -> Value:
        return any(f(v) for f in fs)
    return any_


def _bool_op(node: _BoolOp) -> _Code:
    codes = [_compile(operand) for operand in node.operands]
    fs = [_as_fn(code) for code in codes]
    is_and = node.op == "and"
    # Python's ``a and b`` is a bool when a and b are: then no loop and no bool() is needed.
    plain = all(_is_bool(operand) for operand in node.operands)
    fn: Fn
    if plain and len(fs) == 2:
        a, b = fs
        fn = (lambda v: a(v) and b(v)) if is_and else (lambda v: a(v) or b(v))
    elif plain and len(fs) == 3:
        a, b, c = fs
        fn = ((lambda v: a(v) and b(v) and c(v)) if is_and
              else (lambda v: a(v) or b(v) or c(v)))
    else:
        fn = _all(fs) if is_and else _any(fs)
    return _fold(fn, *codes)


def _no_value(v: Values) -> Value:
    raise KeyError("none")


def _compile(node: _Node) -> _Code:
    if isinstance(node, _Num):
        return _Const(node.value)
    if isinstance(node, _Name):
        return _Lookup(node.name)
    if isinstance(node, _NoValue):
        return _no_value
    if isinstance(node, (_Neg, _Not)):
        code = _compile(node.operand)
        f = _as_fn(code)
        if isinstance(node, _Not):
            return _fold(lambda v: not f(v), code)
        if isinstance(code, _Lookup):
            name = code.name
            return lambda v: -v[name]
        return _fold(lambda v: -f(v), code)
    if isinstance(node, (_Arith, _Compare)):
        codes = [_compile(node.first)] + [_compile(operand) for _, operand in node.rest]
        ops = [op for op, _ in node.rest]
        if len(ops) == 1:
            return _binary(ops[0], codes[0], codes[1])
        fs = [_as_fn(code) for code in codes]
        rest = [(_OPS[op], f) for op, f in zip(ops, fs[1:], strict=True)]
        chain = _arith_chain if isinstance(node, _Arith) else _compare_chain
        return _fold(chain(fs[0], rest), *codes)
    if isinstance(node, _Member):
        code = _compile(node.operand)
        choices = frozenset(node.choices)
        if isinstance(code, _Lookup):
            name = code.name
            if node.negated:
                return lambda v: v[name] not in choices
            return lambda v: v[name] in choices
        f = _as_fn(code)
        if node.negated:
            return _fold(lambda v: f(v) not in choices, code)
        return _fold(lambda v: f(v) in choices, code)
    if isinstance(node, _BoolOp):
        return _bool_op(node)
    codes = [_compile(arg) for arg in node.args]
    fs = [_as_fn(code) for code in codes]
    if node.function == "abs":
        code, f = codes[0], fs[0]
        if isinstance(code, _Lookup):
            name = code.name
            return lambda v: abs(v[name])
        return _fold(lambda v: abs(f(v)), code)
    if node.function in _TRIG:
        trig, g = _TRIG[node.function], fs[0]
        return _fold(lambda v: trig(g(v)), codes[0])
    if node.function == "if":
        condition, then, otherwise = fs
        return _fold(lambda v: then(v) if condition(v) else otherwise(v), *codes)
    function: Callable[..., Value] = min if node.function == "min" else max
    if len(fs) == 2:
        a, b = fs
        return _fold(lambda v: function(a(v), b(v)), *codes)
    return _fold(lambda v: function([f(v) for f in fs]), *codes)
