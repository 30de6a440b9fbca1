"""Text to syntax tree: a recursive-descent parser for TLTL, with no recursion limit.

Precedence, tightest first: arithmetic, comparison, unary (``! F G X``), ``U``/``T``
(right-associative), ``&``, ``|``, ``->`` (right-associative). Every error is a
`SpecError` carrying the 1-based column of the offending token.
"""

from __future__ import annotations

import re
from collections.abc import Generator
from dataclasses import dataclass
from typing import Any

from tl_gym.errors import SpecError
from tl_gym.tltl import ast as nodes
from tl_gym.tltl import foreign
from tl_gym.tltl.ast import COMPARISONS, FUNCTIONS, RESERVED, SIGNAL_NAME_PATTERN, Expr, Formula
from tl_gym.tltl.iterative import drive

# Keywords spelled out, mapped to their symbol.
_KEYWORDS = {
    "not": "!", "and": "&", "or": "|", "implies": "->",
    "eventually": "F", "always": "G", "next": "X", "until": "U", "then": "T",
}
_ALIASES = {"&&": "&", "||": "|", "=>": "->", "**": "^", **foreign.UNICODE_ALIASES}
_DIGITS = r"\d(?:_?\d)*"  # digits, grouped by single underscores as in Python (1_000)
_TOKEN = re.compile(
    r"\s*(?:"
    rf"(?P<num>(?:{_DIGITS}\.?(?:{_DIGITS})?|\.{_DIGITS})(?:[eE][+-]?{_DIGITS})?)"
    rf"|(?P<ident>{SIGNAL_NAME_PATTERN})"  # the names `Var` accepts (θ, x_1); checked in _tokenize
    r"|(?P<op>->|=>|<=|>=|&&|\|\||\*\*|[<>&|!()+\-*/^,¬∧∨→⇒≤≥□◇○])"
    r")"
)


@dataclass(frozen=True)
class _Token:
    kind: str  # "num", "ident", "op" or "end"
    text: str  # normalised: keywords and aliases map to their symbol
    column: int  # 1-based
    raw: str


def _tokenize(text: str) -> list[_Token]:
    tokens: list[_Token] = []
    pos = 0
    while True:
        while pos < len(text) and text[pos].isspace():
            pos += 1
        if pos >= len(text):
            break
        after_operand = bool(tokens) and (tokens[-1].kind in ("num", "ident") or tokens[-1].text == ")")
        if text[pos] in "<!=/" and (other := foreign.preempted(text, pos, after_operand)):  # '<->': not '<', '->'
            raise SpecError(f"unexpected {other[0]!r}: {other[1]}", text, pos + 1)
        match = _TOKEN.match(text, pos)
        if match is None or match.lastgroup is None:
            hint = foreign.hint_at(text, pos, tokens[-1].raw if tokens else None)
            raise SpecError(f"unexpected character {text[pos]!r}" + (f": {hint}" if hint else ""), text, pos + 1)
        kind = match.lastgroup
        raw = match.group(kind)
        column = match.start(kind) + 1
        norm = raw
        if kind == "ident" and not raw.isidentifier():  # \w also matches characters such as '²'
            raise SpecError(f"{raw!r} cannot name a signal (not an identifier)", text, column)
        if kind == "ident" and raw in _KEYWORDS:
            kind, norm = "op", _KEYWORDS[raw]
        elif kind == "ident" and raw in ("F", "G", "X", "U", "T"):
            kind = "op"
        elif kind == "op":
            norm = _ALIASES.get(raw, raw)
        tokens.append(_Token(kind, norm, column, raw))
        pos = match.end()
    tokens.append(_Token("end", "", len(text) + 1, "end of text"))
    return tokens


_Production = Generator[Any, Any, Any]  # a grammar rule: yields the rules it descends into

# Tokens that follow a signal name but never an operator: "F > 10" uses F as a name.
_AFTER_A_NAME = frozenset((*COMPARISONS, "+", "*", "/", "^"))

# Tokens that no arithmetic expression contains: a '(' group holding one is a formula group.
_FORMULA_SYMBOLS = frozenset((*COMPARISONS, "&", "|", "!", "->", "F", "G", "X", "U", "T"))


def _formula_groups(tokens: list[_Token]) -> set[int]:
    """Indices of the '(' tokens whose group (up to the matching ')', or the end) holds a formula token.

    A group that holds a comparison, a connective, a temporal operator or ``true``/``false``
    can only be a parenthesised formula; any other group can only be arithmetic. Deciding
    this in one pass spares the parser trying both readings at every '(' — quadratic
    work (and recursion) on ``((((x > 1))))``.
    """
    marked: set[int] = set()
    open_groups: list[int] = []
    for i, token in enumerate(tokens):
        if token.kind == "op" and token.text == "(":
            open_groups.append(i)
        elif token.kind == "op" and token.text == ")":
            if open_groups:
                closed = open_groups.pop()
                if closed in marked and open_groups:
                    marked.add(open_groups[-1])
        elif open_groups and (
            (token.kind == "op" and token.text in _FORMULA_SYMBOLS)
            or (token.kind == "ident" and token.text in ("true", "false"))
        ):
            marked.add(open_groups[-1])
    for inner, outer in zip(reversed(open_groups), reversed(open_groups[:-1])):  # unclosed groups nest too
        if inner in marked:
            marked.add(outer)
    return marked


def _rename(name: str) -> str:
    """What to do with a signal whose name is reserved."""
    return f"name it otherwise in signals= (e.g. {name}_1)"


class _Parser:
    """Recursive descent written as generators (`tl_gym.tltl.iterative.drive`): no depth limit.

    Each grammar rule yields the rules it descends into instead of calling them, so
    10,000 nested parentheses or operators use no Python stack.
    """

    def __init__(self, text: str):
        self.text = text
        self.tokens = _tokenize(text)
        self.formula_groups = _formula_groups(self.tokens)
        self.pos = 0
        self.predicate_end = -1  # the token after the last predicate read

    # helpers -------------------------------------------------------------------------
    @property
    def tok(self) -> _Token:
        return self.tokens[self.pos]

    def peek(self, offset: int = 1) -> _Token:
        return self.tokens[min(self.pos + offset, len(self.tokens) - 1)]

    def error(self, message: str, token: _Token | None = None) -> SpecError:
        token = token or self.tok
        return SpecError(message, self.text, token.column)

    def reserved_as_name(self, token: _Token, after: _Token) -> SpecError | None:
        """The error for an operator word used as a signal name (``F > 10``, ``until < 3``, ``true > 1``).

        Only on the error path: such text fails anyway, and without this the message pointed at
        the comparison after the word ("expected a predicate ... found '>'").
        """
        if not token.raw.isidentifier() or not (after.kind == "op" and after.text in _AFTER_A_NAME):
            return None
        if token.kind == "ident":  # true, false
            return self.error(f"{token.raw!r} is a constant and cannot name a signal", token)
        what = "a temporal operator" if token.text in ("F", "G", "X", "U", "T") else "reserved"
        return self.error(f"{token.raw!r} is {what} and cannot name a signal: {_rename(token.raw)}", token)

    def with_hint(self, message: str, word: str) -> str:
        """``message``, with what to write instead if ``word`` is another tool's syntax (`foreign.hint_for_word`)."""
        hint = foreign.hint_for_word(word)
        return f"{message}: {hint}" if hint else message

    def describe(self, token: _Token) -> str:
        return "the end of the formula" if token.kind == "end" else repr(token.raw)

    def accept(self, *symbols: str) -> _Token | None:
        if self.tok.kind == "op" and self.tok.text in symbols:
            token = self.tok
            self.pos += 1
            return token
        return None

    def expect(self, symbol: str, what: str) -> _Token:
        token = self.accept(symbol)
        if token is None:
            raise self.error(f"expected {what}, found {self.describe(self.tok)}")
        return token

    # formulas ---------------------------------------------------------------------------
    def parse(self) -> Formula:
        if self.tok.kind == "end":
            raise self.error("empty formula")
        formula = drive(self.implies())
        if self.tok.kind != "end":
            if self.tok.text in COMPARISONS and self.pos == self.predicate_end:
                raise self.error("comparisons do not chain; join them with '&'")
            if self.pos and (misused := self.reserved_as_name(self.tokens[self.pos - 1], self.tok)):
                raise misused
            raise self.error(self.with_hint(f"unexpected {self.describe(self.tok)} after a complete formula",
                                            self.tok.raw))
        return formula

    def implies(self) -> _Production:
        # right-associative: collect the chain, then nest it from the right
        chain = [(yield self.disjunction())]
        while self.accept("->"):
            chain.append((yield self.disjunction()))
        formula = chain.pop()
        while chain:
            formula = nodes.Implies(chain.pop(), formula)
        return formula

    def disjunction(self) -> _Production:
        operands = [(yield self.conjunction())]
        while self.accept("|"):
            operands.append((yield self.conjunction()))
        return operands[0] if len(operands) == 1 else nodes.Or(tuple(operands))

    def conjunction(self) -> _Production:
        operands = [(yield self.binary_temporal())]
        while self.accept("&"):
            operands.append((yield self.binary_temporal()))
        return operands[0] if len(operands) == 1 else nodes.And(tuple(operands))

    def binary_temporal(self) -> _Production:
        # right-associative: a U b T c is a U (b T c)
        operands = [(yield self.unary())]
        kinds: list[type[Formula]] = []
        while (token := self.accept("U", "T")) is not None:
            kinds.append(nodes.Until if token.text == "U" else nodes.Then)
            operands.append((yield self.unary()))
        formula = operands.pop()
        while kinds:
            formula = kinds.pop()(operands.pop(), formula)  # type: ignore[call-arg]
        return formula

    def unary(self) -> _Production:
        prefixes: list[type[Formula]] = []
        while (token := self.accept("!", "F", "G", "X")) is not None:
            prefixes.append({"!": nodes.Not, "F": nodes.Eventually, "G": nodes.Always, "X": nodes.Next}[token.text])
        formula = yield self.primary()
        while prefixes:
            formula = prefixes.pop()(formula)  # type: ignore[call-arg]
        return formula

    def primary(self) -> _Production:
        token = self.tok
        if token.kind == "ident" and token.text in ("true", "false"):
            self.pos += 1
            return nodes.Constant(token.text == "true")
        if token.kind == "op" and token.text == "(" and self.pos in self.formula_groups:
            self.pos += 1  # a parenthesised formula (an arithmetic group starts a predicate, below)
            inner = yield self.implies()
            self.expect(")", "')' to close the '(' at column " + str(token.column))
            return inner
        if token.kind in ("num", "ident") or (token.kind == "op" and token.text in ("-", "(")):
            return (yield self.predicate())
        if token.kind == "end":
            raise self.error("the formula ends where an operand was expected")
        before = self.tokens[self.pos - 1] if self.pos else None
        if before is not None and before.text in ("!", "F", "G", "X"):  # "F > 10": was F a name?
            if misused := self.reserved_as_name(before, token):
                raise misused
        if misused := self.reserved_as_name(token, self.peek(1)):  # "U > 0", "x > 1 & then < 2"
            raise misused
        raise self.error(f"expected a predicate, 'true', 'false' or '(', found {self.describe(token)}")

    def predicate(self) -> _Production:
        lhs = yield self.expression()
        token = self.tok
        if token.kind != "op" or token.text not in COMPARISONS:
            found = self.describe(token)
            message = f"expected a comparison ({' '.join(COMPARISONS)}) after {str(lhs)!r}, found {found}"
            if token.raw in ("=>", "⇒"):
                message += f": did you mean '>='? ({token.raw!r} is read as '->')"
            elif isinstance(lhs, nodes.Var):
                # a word of another tool used as an operator (an operand follows: "GF x > 0"), or a constant
                operator_like = token.kind in ("num", "ident") or token.text in ("(", "!", "F", "G", "X")
                constant = lhs.name.lower() in ("true", "false")
                hint = foreign.hint_for_word(lhs.name) if operator_like or constant else None
                real = f"signals are real numbers, compared to make a predicate (e.g. {lhs.name} > 0.5)"
                message += f": {hint or real}"
            raise self.error(message)
        self.pos += 1
        predicate = nodes.Predicate(lhs, token.text, (yield self.expression()))
        self.predicate_end = self.pos
        return predicate

    # arithmetic -------------------------------------------------------------------------
    def plain(self, binds_tighter: tuple[str, ...]) -> Expr | None:
        """A lone number or signal name that no operator in ``binds_tighter`` extends, or None.

        The common operand, read without descending through the grammar's levels.
        """
        token, nxt = self.tok, self.peek(1)
        if nxt.kind == "op" and nxt.text in binds_tighter:
            return None
        if token.kind == "num" and float(token.raw) != float("inf"):
            self.pos += 1
            return nodes.Num(float(token.raw))
        if token.kind == "ident" and token.text not in RESERVED:
            self.pos += 1
            return nodes.Var(token.text)
        return None

    def expression(self) -> _Production:
        left = self.plain(("*", "/", "^", "(")) or (yield self.term())
        while (token := self.accept("+", "-")) is not None:
            right = self.plain(("*", "/", "^", "(")) or (yield self.term())
            left = nodes.BinOp(token.text, left, right)
        return left

    def term(self) -> _Production:
        left = self.plain(("^", "(")) or (yield self.factor())
        while (token := self.accept("*", "/")) is not None:
            left = nodes.BinOp(token.text, left, self.plain(("^", "(")) or (yield self.factor()))
        return left

    def factor(self) -> _Production:
        negations = 0
        while self.accept("-"):
            nxt = self.peek(1)
            if self.tok.kind == "num" and not (nxt.kind == "op" and nxt.text == "^"):
                # A negative literal is one number, so `-3` prints and parses back alike.
                value = self.finite_number(self.tok, "-")
                self.pos += 1
                expr: Expr = nodes.Num(-value)
                break
            negations += 1
        else:
            expr = yield self.power()
        for _ in range(negations):
            expr = nodes.Neg(expr)
        return expr

    def power(self) -> _Production:
        base = yield self.atom()
        if self.accept("^"):
            return nodes.BinOp("^", base, (yield self.factor()))
        return base

    def finite_number(self, token: _Token, sign: str = "") -> float:
        """The value of a number token; one that overflows to inf (``1e999``) is a SpecError at its column."""
        value = float(token.raw)
        if value == float("inf"):
            raise self.error(f"number {sign}{token.raw} is too large", token)
        return value

    def atom(self) -> _Production:
        token = self.tok
        if token.kind == "num":
            self.pos += 1
            return nodes.Num(self.finite_number(token))
        if token.kind == "ident":
            self.pos += 1
            if token.text in FUNCTIONS:
                return (yield self.call(token))
            if token.text in RESERVED:
                message = f"{token.raw!r} is reserved and cannot name a signal"
                if self.tok.kind == "op" and self.tok.text in COMPARISONS:  # "inf > 1": a signal's name
                    raise self.error(f"{message}: {_rename(token.raw)}", token)
                raise self.error(self.with_hint(message, token.raw), token)
            if self.tok.kind == "op" and self.tok.text == "(":
                known = " ".join(FUNCTIONS)
                message = f"unknown function {token.raw!r} (functions: {known})"
                if foreign.hint_for_word(token.raw) is None:
                    message += ("; operators: ! F G X U T (not eventually always next until then)"
                                if self.pos in self.formula_groups else
                                f"; a signal takes no argument: write {token.raw}, not {token.raw}(t)")
                raise self.error(self.with_hint(message, token.raw), token)
            return nodes.Var(token.text)
        if self.tok.kind == "op" and self.tok.text == "(" and self.pos in self.formula_groups:  # -(x > 0)
            raise self.error("a formula in parentheses cannot be a number: negate a formula with ! (or not), "
                             "and give functions and arithmetic numbers, not formulas")
        if self.accept("("):
            inner = yield self.expression()
            self.expect(")", f"')' to close the '(' at column {token.column}")
            return inner
        if token.kind == "op" and token.text in ("F", "G", "X", "U", "T"):
            raise self.error(f"{token.raw!r} is a temporal operator and cannot name a signal", token)
        raise self.error(f"expected a number, a signal name or '(', found {self.describe(token)}")

    def call(self, name: _Token) -> _Production:
        self.expect("(", f"'(' after the function {name.raw!r}")
        args = [(yield self.expression())]
        while self.accept(","):
            args.append((yield self.expression()))
        if self.tok.kind == "op" and self.tok.text in COMPARISONS:
            raise self.error(f"expected ')' to close the call to {name.raw!r}, found {self.describe(self.tok)}: "
                             "functions take arithmetic, not formulas")
        self.expect(")", f"')' to close the call to {name.raw!r}")
        arity = FUNCTIONS[name.text]
        if arity > 0 and len(args) != arity:
            raise self.error(f"{name.raw}() takes {arity} argument, got {len(args)}", name)
        return nodes.Call(name.text, tuple(args))


def parse(text: str) -> Formula:
    """Parse TLTL text into a `Formula`.

    Example:
        >>> from tl_gym import parse
        >>> phi = parse("F(s > 5 & s < 10)")
        >>> phi.robustness({"s": [11.0, 6.0, 7.0]})
        2.0

    Raises:
        SpecError: the text is malformed; the message shows the column and a caret.
        TypeError: ``text`` is neither a string nor a `Formula`.
    """
    if isinstance(text, Formula):
        return text
    if not isinstance(text, str):
        raise TypeError(f"parse() takes the formula as a string, got {type(text).__name__}")
    return _Parser(text).parse()
