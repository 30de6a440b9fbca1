"""Text to syntax tree: a recursive-descent parser for TLTL.

Precedence, tightest first: arithmetic, comparison, unary (``! F G X``), ``U``/``T``
(right-associative), ``&``, ``|``, ``->`` (right-associative). Every error is a
`SpecError` carrying the 1-based column of the offending token.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from tl_gym.errors import SpecError
from tl_gym.tltl.ast import (
    COMPARISONS,
    FUNCTIONS,
    RESERVED,
    Always,
    And,
    BinOp,
    Call,
    Constant,
    Eventually,
    Expr,
    Formula,
    Implies,
    Neg,
    Next,
    Not,
    Num,
    Or,
    Predicate,
    Then,
    Until,
    Var,
)

# Keywords spelled out, mapped to their symbol.
_KEYWORDS = {
    "not": "!", "and": "&", "or": "|", "implies": "->",
    "eventually": "F", "always": "G", "next": "X", "until": "U", "then": "T",
}
_ALIASES = {"&&": "&", "||": "|", "=>": "->", "**": "^"}
_TOKEN = re.compile(
    r"\s*(?:"
    r"(?P<num>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)"
    r"|(?P<ident>[A-Za-z_][A-Za-z0-9_]*)"
    r"|(?P<op>->|=>|<=|>=|&&|\|\||\*\*|[<>&|!()+\-*/^,])"
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
        match = _TOKEN.match(text, pos)
        if match is None or match.lastgroup is None:
            raise SpecError(f"unexpected character {text[pos]!r}", text, pos + 1)
        kind = match.lastgroup
        raw = match.group(kind)
        column = match.start(kind) + 1
        norm = raw
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


class _Parser:
    def __init__(self, text: str):
        self.text = text
        self.tokens = _tokenize(text)
        self.pos = 0
        self.last_primary: Formula | None = None

    # helpers -------------------------------------------------------------------------
    @property
    def tok(self) -> _Token:
        return self.tokens[self.pos]

    def peek(self, offset: int = 1) -> _Token:
        return self.tokens[min(self.pos + offset, len(self.tokens) - 1)]

    def error(self, message: str, token: _Token | None = None) -> SpecError:
        token = token or self.tok
        return SpecError(message, self.text, token.column)

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
        formula = self.implies()
        if self.tok.kind != "end":
            if self.tok.text in COMPARISONS and isinstance(self.last_primary, Predicate):
                raise self.error("comparisons do not chain; join them with '&'")
            raise self.error(f"unexpected {self.describe(self.tok)} after a complete formula")
        return formula

    def implies(self) -> Formula:
        left = self.disjunction()
        if self.accept("->"):
            return Implies(left, self.implies())
        return left

    def disjunction(self) -> Formula:
        operands = [self.conjunction()]
        while self.accept("|"):
            operands.append(self.conjunction())
        return operands[0] if len(operands) == 1 else Or(tuple(operands))

    def conjunction(self) -> Formula:
        operands = [self.binary_temporal()]
        while self.accept("&"):
            operands.append(self.binary_temporal())
        return operands[0] if len(operands) == 1 else And(tuple(operands))

    def binary_temporal(self) -> Formula:
        left = self.unary()
        if self.accept("U"):
            return Until(left, self.binary_temporal())
        if self.accept("T"):
            return Then(left, self.binary_temporal())
        return left

    def unary(self) -> Formula:
        for symbol, node in (("!", Not), ("F", Eventually), ("G", Always), ("X", Next)):
            if self.accept(symbol):
                return node(self.unary())
        return self.primary()

    def primary(self) -> Formula:
        token = self.tok
        if token.kind == "ident" and token.text in ("true", "false"):
            self.pos += 1
            self.last_primary = Constant(token.text == "true")
            return self.last_primary
        if token.kind == "op" and token.text == "(":
            # '(' opens either a parenthesised formula or an arithmetic group of a
            # predicate; try the predicate first and keep the error that got furthest.
            start = self.pos
            try:
                return self.predicate()
            except SpecError as as_predicate:
                self.pos = start
                try:
                    self.expect("(", "'('")
                    inner = self.implies()
                    self.expect(")", "')' to close the '(' at column " + str(token.column))
                    return inner
                except SpecError as as_formula:
                    raise max(as_predicate, as_formula, key=lambda e: e.column) from None
        if token.kind in ("num", "ident") or (token.kind == "op" and token.text == "-"):
            return self.predicate()
        if token.kind == "end":
            raise self.error("the formula ends where an operand was expected")
        raise self.error(f"expected a predicate, 'true', 'false' or '(', found {self.describe(token)}")

    def predicate(self) -> Formula:
        lhs = self.expression()
        token = self.tok
        if token.kind != "op" or token.text not in COMPARISONS:
            raise self.error(
                f"expected a comparison ({' '.join(COMPARISONS)}) after {str(lhs)!r}, "
                f"found {self.describe(token)}"
            )
        self.pos += 1
        self.last_primary = Predicate(lhs, token.text, self.expression())
        return self.last_primary

    # arithmetic -------------------------------------------------------------------------
    def expression(self) -> Expr:
        left = self.term()
        while (token := self.accept("+", "-")) is not None:
            left = BinOp(token.text, left, self.term())
        return left

    def term(self) -> Expr:
        left = self.factor()
        while (token := self.accept("*", "/")) is not None:
            left = BinOp(token.text, left, self.factor())
        return left

    def factor(self) -> Expr:
        if self.accept("-"):
            nxt = self.peek(1)
            if self.tok.kind == "num" and not (nxt.kind == "op" and nxt.text == "^"):
                # A negative literal is one number, so `-3` prints and parses back alike.
                value = float(self.tok.raw)
                self.pos += 1
                return Num(-value)
            return Neg(self.factor())
        return self.power()

    def power(self) -> Expr:
        base = self.atom()
        if self.accept("^"):
            return BinOp("^", base, self.factor())
        return base

    def atom(self) -> Expr:
        token = self.tok
        if token.kind == "num":
            self.pos += 1
            value = float(token.raw)
            if value == float("inf"):
                raise self.error(f"number {token.raw} is too large", token)
            return Num(value)
        if token.kind == "ident":
            self.pos += 1
            if token.text in FUNCTIONS:
                return self.call(token)
            if token.text in RESERVED:
                raise self.error(f"{token.raw!r} is reserved and cannot name a signal", token)
            if self.tok.kind == "op" and self.tok.text == "(":
                known = " ".join(FUNCTIONS)
                raise self.error(f"unknown function {token.raw!r} (functions: {known})", token)
            return Var(token.text)
        if self.accept("("):
            inner = self.expression()
            self.expect(")", f"')' to close the '(' at column {token.column}")
            return inner
        if token.kind == "op" and token.text in ("F", "G", "X", "U", "T"):
            raise self.error(f"{token.raw!r} is a temporal operator and cannot name a signal", token)
        raise self.error(f"expected a number, a signal name or '(', found {self.describe(token)}")

    def call(self, name: _Token) -> Expr:
        self.expect("(", f"'(' after the function {name.raw!r}")
        args = [self.expression()]
        while self.accept(","):
            args.append(self.expression())
        self.expect(")", f"')' to close the call to {name.raw!r}")
        arity = FUNCTIONS[name.text]
        if arity > 0 and len(args) != arity:
            raise self.error(f"{name.raw}() takes {arity} argument, got {len(args)}", name)
        return Call(name.text, tuple(args))


def parse(text: str) -> Formula:
    """Parse TLTL text into a `Formula`.

    Example:
        >>> from tl_gym import parse
        >>> phi = parse("F(s > 5 & s < 10)")
        >>> phi.robustness({"s": [11.0, 6.0, 7.0]})
        2.0

    Raises:
        SpecError: the text is malformed; the message shows the column and a caret.
    """
    if isinstance(text, Formula):
        return text
    if not isinstance(text, str):
        raise TypeError(f"parse() takes the formula as a string, got {type(text).__name__}")
    return _Parser(text).parse()
