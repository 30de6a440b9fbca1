"""TLTL syntax tree: arithmetic expressions over signals and the formula nodes.

Nodes carry no semantics: they store their children and print themselves in
the canonical syntax, so that ``parse(str(f)) == f`` for every formula ``f``.
The evaluators (``exact``, ``smooth``, ``bracket``) dispatch on these classes.

A chain of ``&`` (or of ``|``) is one n-ary node whatever its parentheses: the
constructors flatten nested conjunctions (disjunctions), as the paper's Eq. 17
treats the goal box, so regrouping never changes a smoothed value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Union

if TYPE_CHECKING:
    import numpy as np

    from tl_gym.tltl.trace import Trace

# Words that cannot name a signal (operators, keywords, constants, functions).
RESERVED = frozenset(
    "F G X U T true false not and or implies eventually always next until then "
    "abs sqrt exp log min max".split()
)
FUNCTIONS = {"abs": 1, "sqrt": 1, "exp": 1, "log": 1, "min": -1, "max": -1}
COMPARISONS = ("<", "<=", ">", ">=")
ARITHMETIC_OPERATORS = ("+", "-", "*", "/", "^")

# Printing precedence of expressions, loosest first.
_E_ADD, _E_MUL, _E_UNARY, _E_POW, _E_ATOM = 1, 2, 3, 4, 5
# Printing precedence of formulas, loosest first.
_F_IMPLIES, _F_OR, _F_AND, _F_BINARY_TEMPORAL, _F_UNARY, _F_ATOM = 1, 2, 3, 4, 5, 6


def _wrap(text: str, own: int, needed: int) -> str:
    return f"({text})" if own < needed else text


# --------------------------------------------------------------------------- expressions


class Expr:
    """Arithmetic over signals; comparing two expressions makes a `Predicate`."""

    precedence: ClassVar[int] = _E_ATOM

    # Arithmetic builders -------------------------------------------------------
    def __add__(self, other: ExprLike) -> Expr:
        return BinOp("+", self, as_expr(other))

    def __radd__(self, other: ExprLike) -> Expr:
        return BinOp("+", as_expr(other), self)

    def __sub__(self, other: ExprLike) -> Expr:
        return BinOp("-", self, as_expr(other))

    def __rsub__(self, other: ExprLike) -> Expr:
        return BinOp("-", as_expr(other), self)

    def __mul__(self, other: ExprLike) -> Expr:
        return BinOp("*", self, as_expr(other))

    def __rmul__(self, other: ExprLike) -> Expr:
        return BinOp("*", as_expr(other), self)

    def __truediv__(self, other: ExprLike) -> Expr:
        return BinOp("/", self, as_expr(other))

    def __rtruediv__(self, other: ExprLike) -> Expr:
        return BinOp("/", as_expr(other), self)

    def __pow__(self, other: ExprLike) -> Expr:
        return BinOp("^", self, as_expr(other))

    def __rpow__(self, other: ExprLike) -> Expr:
        return BinOp("^", as_expr(other), self)

    def __neg__(self) -> Expr:
        return Neg(self)

    def __abs__(self) -> Expr:
        return Call("abs", (self,))

    # Comparisons build predicates ------------------------------------------------
    def __lt__(self, other: ExprLike) -> Predicate:
        return Predicate(self, "<", as_expr(other))

    def __le__(self, other: ExprLike) -> Predicate:
        return Predicate(self, "<=", as_expr(other))

    def __gt__(self, other: ExprLike) -> Predicate:
        return Predicate(self, ">", as_expr(other))

    def __ge__(self, other: ExprLike) -> Predicate:
        return Predicate(self, ">=", as_expr(other))

    def signal_names(self) -> tuple[str, ...]:
        """Signal names this expression reads, in order of first appearance."""
        names: dict[str, None] = {}
        _collect_expr_signals(self, names)
        return tuple(names)


ExprLike = Union[Expr, int, float]


@dataclass(frozen=True, eq=True)
class Var(Expr):
    """A signal read from the trace, by name."""

    name: str

    def __post_init__(self) -> None:
        if not self.name.isidentifier() or self.name in RESERVED:
            raise ValueError(f"{self.name!r} cannot name a signal (reserved or not an identifier)")

    def __str__(self) -> str:
        return self.name


@dataclass(frozen=True, eq=True)
class Num(Expr):
    """A finite number."""

    value: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "value", float(self.value))
        if not math.isfinite(self.value):
            raise ValueError(f"a number in a formula must be finite, got {self.value}")

    @property
    def precedence(self) -> int:  # type: ignore[override]
        return _E_UNARY if self.value < 0 else _E_ATOM

    def __str__(self) -> str:
        v = self.value
        if v.is_integer() and abs(v) < 1e16:
            return str(int(v))
        return repr(v)


@dataclass(frozen=True, eq=True)
class Neg(Expr):
    """Unary minus."""

    operand: Expr
    precedence: ClassVar[int] = _E_UNARY

    def __str__(self) -> str:
        inner = str(self.operand)
        if isinstance(self.operand, Num) and self.operand.precedence == _E_ATOM:
            return f"-({inner})"  # keep `-3` for Num(-3): a literal folds into the number
        return "-" + (" " if inner.startswith("-") else "") + _wrap(inner, self.operand.precedence, _E_UNARY)


@dataclass(frozen=True, eq=True)
class BinOp(Expr):
    """A binary arithmetic operation: ``+ - * /`` or ``^`` (power)."""

    op: str
    left: Expr
    right: Expr

    def __post_init__(self) -> None:
        if self.op not in ARITHMETIC_OPERATORS:
            raise ValueError(f"unknown arithmetic operator {self.op!r}")

    @property
    def precedence(self) -> int:  # type: ignore[override]
        return {"+": _E_ADD, "-": _E_ADD, "*": _E_MUL, "/": _E_MUL, "^": _E_POW}[self.op]

    def __str__(self) -> str:
        own = self.precedence
        if self.op == "^":  # right-associative; the exponent may carry a unary minus
            left = _wrap(str(self.left), self.left.precedence, _E_ATOM)
            right = _wrap(str(self.right), self.right.precedence, _E_UNARY)
        else:  # left-associative
            left = _wrap(str(self.left), self.left.precedence, own)
            right = _wrap(str(self.right), self.right.precedence, own + 1)
        return f"{left} {self.op} {right}"


@dataclass(frozen=True, eq=True)
class Call(Expr):
    """A function of expressions: ``abs sqrt exp log`` (one argument), ``min max`` (one or more)."""

    func: str
    args: tuple[Expr, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "args", tuple(self.args))
        arity = FUNCTIONS.get(self.func)
        if arity is None:
            raise ValueError(f"unknown function {self.func!r}; known: {', '.join(FUNCTIONS)}")
        if (arity > 0 and len(self.args) != arity) or len(self.args) == 0:
            raise ValueError(f"{self.func} takes {arity if arity > 0 else 'one or more'} argument(s)")

    def __str__(self) -> str:
        return f"{self.func}({', '.join(str(a) for a in self.args)})"


def as_expr(value: ExprLike) -> Expr:
    """Turn a Python number into a `Num` (negative numbers fold into the literal)."""
    if isinstance(value, Expr):
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"expected an expression or a number, got {type(value).__name__}: {value!r}")
    return Num(float(value))


def _collect_expr_signals(expr: Expr, names: dict[str, None]) -> None:
    if isinstance(expr, Var):
        names.setdefault(expr.name, None)
    elif isinstance(expr, Neg):
        _collect_expr_signals(expr.operand, names)
    elif isinstance(expr, BinOp):
        _collect_expr_signals(expr.left, names)
        _collect_expr_signals(expr.right, names)
    elif isinstance(expr, Call):
        for arg in expr.args:
            _collect_expr_signals(arg, names)


# --------------------------------------------------------------------------- formulas


class Formula:
    """A TLTL formula; the evaluation methods are the public API.

    Build one with `tl_gym.parse` or with the helpers of `tl_gym.logic`.
    ``&``, ``|`` and ``~`` combine formulas; ``>>`` is implication.
    """

    precedence: ClassVar[int] = _F_ATOM

    # Boolean builders --------------------------------------------------------------
    def __and__(self, other: Formula) -> Formula:
        return And((self, _as_formula(other)))

    def __or__(self, other: Formula) -> Formula:
        return Or((self, _as_formula(other)))

    def __invert__(self) -> Formula:
        return Not(self)

    def __rshift__(self, other: Formula) -> Formula:
        return Implies(self, _as_formula(other))

    def __bool__(self) -> bool:
        raise TypeError(
            "a Formula has no truth value in Python; use `&`, `|`, `~` to combine formulas "
            "(not `and`, `or`, `not`), and `formula.satisfied(trace)` to check a trace"
        )

    # Introspection -------------------------------------------------------------------
    @property
    def children(self) -> tuple[Formula, ...]:
        """Direct sub-formulas, left to right."""
        return ()

    @property
    def signals(self) -> tuple[str, ...]:
        """Signal names the formula reads, in order of first appearance."""
        names: dict[str, None] = {}
        for node in self.walk():
            if isinstance(node, Predicate):
                for name in node.lhs.signal_names() + node.rhs.signal_names():
                    names.setdefault(name, None)
        return tuple(names)

    def walk(self) -> list[Formula]:
        """Every node of the formula, parents before children (pre-order)."""
        out: list[Formula] = [self]
        for child in self.children:
            out.extend(child.walk())
        return out

    @property
    def is_temporal(self) -> bool:
        """Whether any temporal operator occurs in the formula."""
        return any(isinstance(n, (Next, Eventually, Always, Until, Then)) for n in self.walk())

    # Semantics (the evaluators live in their own modules) ---------------------------
    def robustness(self, trace: Trace, rho_max: float = math.inf) -> float | np.ndarray:
        """Robustness of the trace at position 0 (> 0 means it satisfies the formula).

        Args:
            trace: maps each signal name to an array of shape ``(T,)`` or ``(N, T)``;
                extra names are ignored.
            rho_max: the value of ``true`` (and minus that of ``false`` and of ``X φ``
                at the last state).

        Returns:
            A float for ``(T,)`` signals, an array of shape ``(N,)`` for ``(N, T)``.
        """
        from tl_gym.tltl import exact

        return exact.robustness(self, trace, rho_max)

    def robustness_over_time(self, trace: Trace, rho_max: float = math.inf) -> np.ndarray:
        """Robustness of every suffix: entry ``t`` judges the states ``t … T-1``.

        Returns an array of shape ``(T,)`` or ``(N, T)``; entry 0 is `robustness`.
        """
        from tl_gym.tltl import exact

        return exact.robustness_over_time(self, trace, rho_max)

    def satisfied(self, trace: Trace) -> bool | np.ndarray:
        """Boolean semantics at position 0: a bool, or a bool array of shape ``(N,)``."""
        from tl_gym.tltl import exact

        return exact.satisfied(self, trace)

    def smooth_robustness(self, trace: Trace, beta: float, rho_max: float = math.inf, form: str = "nested") -> Any:
        """Log-sum-exp smoothed robustness with sharpness ``beta`` (paper, section V).

        Every max and min of the definition, the ones over time included, becomes
        ``±log(Σ exp(±β x))/β``, nested as the definition nests. Given torch tensors
        the result is a torch tensor differentiable by autograd; given numpy arrays, a
        float or an ``(N,)`` array (computed in float64). ``form="linear"`` trades the
        prescribed O(T²) nesting of a ``T`` under another temporal operator for an
        O(T) smoothing with the same limit and bracket (see `tl_gym.tltl.smooth`).
        """
        from tl_gym.tltl import smooth

        return smooth.smooth_robustness(self, trace, beta, rho_max, form)

    def smooth_robustness_over_time(
        self, trace: Trace, beta: float, rho_max: float = math.inf, form: str = "nested"
    ) -> Any:
        """Smoothed robustness of every suffix, as a torch tensor ``(T,)`` or ``(N, T)``."""
        from tl_gym.tltl import smooth

        return smooth.smooth_over_time(self, trace, beta, rho_max, form)

    def smoothing_bracket(self, horizon: int, beta: float) -> tuple[float, float]:
        """Bounds ``(below, above)`` with ``ρ - below ≤ ρ̂ ≤ ρ + above`` (paper, Lemma 1).

        Each max node of ``n`` terms adds ``log(n)/β`` above, each min node
        ``log(n)/β`` below, taken along the worst path, for traces of length ``horizon``.
        """
        from tl_gym.tltl import bracket

        return bracket.smoothing_bracket(self, horizon, beta)


def _as_formula(value: Any) -> Formula:
    if isinstance(value, Formula):
        return value
    if isinstance(value, bool):
        return Constant(value)
    raise TypeError(f"expected a Formula, got {type(value).__name__}: {value!r}")


def _child_str(child: Formula, needed: int) -> str:
    return _wrap(str(child), child.precedence, needed)


@dataclass(frozen=True, eq=True)
class Constant(Formula):
    """``true`` (robustness ρ_max) or ``false`` (−ρ_max)."""

    value: bool

    def __str__(self) -> str:
        return "true" if self.value else "false"


@dataclass(frozen=True, eq=True)
class Predicate(Formula):
    """``lhs op rhs``: ``a < b`` and ``a <= b`` have robustness ``b - a``; ``>``, ``>=`` have ``a - b``."""

    lhs: Expr
    op: str
    rhs: Expr

    def __post_init__(self) -> None:
        if self.op not in COMPARISONS:
            raise ValueError(f"unknown comparison {self.op!r}; use one of {COMPARISONS}")

    def __str__(self) -> str:
        return f"{self.lhs} {self.op} {self.rhs}"


@dataclass(frozen=True, eq=True)
class Not(Formula):
    """Negation: robustness ``-ρ(φ)``."""

    child: Formula
    precedence: ClassVar[int] = _F_UNARY

    @property
    def children(self) -> tuple[Formula, ...]:
        return (self.child,)

    def __str__(self) -> str:
        return "!" + _child_str(self.child, _F_UNARY)


class _NAry(Formula):
    """Shared construction of the n-ary connectives: flattened, at least two operands."""

    operands: tuple[Formula, ...]
    symbol: ClassVar[str]

    @property
    def children(self) -> tuple[Formula, ...]:
        return self.operands

    def __post_init__(self) -> None:
        flat: list[Formula] = []
        for child in self.operands:
            child = _as_formula(child)
            flat.extend(child.children if type(child) is type(self) else (child,))
        if len(flat) < 2:
            raise ValueError(f"{type(self).__name__} needs at least two operands, got {len(flat)}")
        object.__setattr__(self, "operands", tuple(flat))

    def __str__(self) -> str:
        return f" {self.symbol} ".join(_child_str(c, self.precedence + 1) for c in self.children)


@dataclass(frozen=True, eq=True)
class And(_NAry):
    """Conjunction of two or more formulas: one n-ary min."""

    operands: tuple[Formula, ...]
    symbol: ClassVar[str] = "&"
    precedence: ClassVar[int] = _F_AND


@dataclass(frozen=True, eq=True)
class Or(_NAry):
    """Disjunction of two or more formulas: one n-ary max."""

    operands: tuple[Formula, ...]
    symbol: ClassVar[str] = "|"
    precedence: ClassVar[int] = _F_OR


class _Binary(Formula):
    """Shared printing of the right-associative binary operators."""

    left: Formula
    right: Formula
    symbol: ClassVar[str]

    @property
    def children(self) -> tuple[Formula, ...]:
        return (self.left, self.right)

    def __str__(self) -> str:
        own = self.precedence
        return f"{_child_str(self.left, own + 1)} {self.symbol} {_child_str(self.right, own)}"


@dataclass(frozen=True, eq=True)
class Implies(_Binary):
    """``φ -> ψ``: robustness ``max(-ρ(φ), ρ(ψ))``."""

    left: Formula
    right: Formula
    symbol: ClassVar[str] = "->"
    precedence: ClassVar[int] = _F_IMPLIES


@dataclass(frozen=True, eq=True)
class Until(_Binary):
    """``φ U ψ``: ψ holds at some t', φ at every t'' before it (judged on s_{t''..t'-1})."""

    left: Formula
    right: Formula
    symbol: ClassVar[str] = "U"
    precedence: ClassVar[int] = _F_BINARY_TEMPORAL


@dataclass(frozen=True, eq=True)
class Then(_Binary):
    """``φ T ψ``: ψ holds at some t', φ at some t'' before it (judged on s_{t''..t'-1})."""

    left: Formula
    right: Formula
    symbol: ClassVar[str] = "T"
    precedence: ClassVar[int] = _F_BINARY_TEMPORAL


class _Unary(Formula):
    child: Formula
    symbol: ClassVar[str]
    precedence: ClassVar[int] = _F_UNARY

    @property
    def children(self) -> tuple[Formula, ...]:
        return (self.child,)

    def __str__(self) -> str:
        return f"{self.symbol} " + _child_str(self.child, _F_UNARY)


@dataclass(frozen=True, eq=True)
class Next(_Unary):
    """``X φ``: φ from the next state; −ρ_max at the last state."""

    child: Formula
    symbol: ClassVar[str] = "X"


@dataclass(frozen=True, eq=True)
class Eventually(_Unary):
    """``F φ``: max over the remaining positions."""

    child: Formula
    symbol: ClassVar[str] = "F"


@dataclass(frozen=True, eq=True)
class Always(_Unary):
    """``G φ``: min over the remaining positions."""

    child: Formula
    symbol: ClassVar[str] = "G"


FORMULA_NODES: tuple[type[Formula], ...] = (
    Constant, Predicate, Not, And, Or, Implies, Next, Eventually, Always, Until, Then,
)


def _cached_hash(self: Any) -> int:
    """Structural hash, computed once per node: evaluators key their caches by node."""
    try:
        return self.__dict__["_hash"]
    except KeyError:
        value = hash((type(self).__name__, *(getattr(self, f) for f in self.__dataclass_fields__)))
        object.__setattr__(self, "_hash", value)
        return value


def _state_without_hash(self: Any) -> dict[str, Any]:
    """Pickle state without the cached hash: string hashes differ between processes."""
    state = dict(self.__dict__)
    state.pop("_hash", None)
    return state


for _cls in (*FORMULA_NODES, Var, Num, Neg, BinOp, Call):
    _cls.__hash__ = _cached_hash  # type: ignore[method-assign]
    _cls.__getstate__ = _state_without_hash  # type: ignore[attr-defined]
