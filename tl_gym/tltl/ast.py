"""TLTL syntax tree: arithmetic expressions over signals and the formula nodes.

Nodes carry no semantics: they store their children and print themselves in
the canonical syntax, so that ``parse(str(f)) == f`` for every formula ``f``.
The evaluators (``exact``, ``smooth``, ``bracket``) dispatch on these classes.

A chain of ``&`` (or of ``|``) is one n-ary node whatever its parentheses: the
constructors flatten nested conjunctions (disjunctions), as the paper's Eq. 17
treats the goal box, so regrouping never changes a smoothed value.

Every structural operation — printing, ``repr``, hashing, equality, `Formula.walk`,
`Formula.signals`, `Formula.is_temporal` — runs on explicit stacks, so a formula nested
10,000 levels deep prints, hashes and compares like a small one (docs/engine.md, "Depth").
Nodes are immutable, so what is derived from a whole sub-tree (hash, signals, whether it is
temporal, its nesting depth) is computed once, bottom-up, and kept on the node.
"""

from __future__ import annotations

import copyreg
import dataclasses
import math
import numbers
import operator
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Union

if TYPE_CHECKING:
    import numpy as np

    from tl_gym.tltl.trace import Trace

# Words that cannot name a signal (operators, keywords, constants, functions).
#: What can name a signal: a letter or underscore, then letters, digits, underscores (the parser's `ident` token)
SIGNAL_NAME_PATTERN = r"[^\W\d]\w*"
_SIGNAL_NAME = re.compile(SIGNAL_NAME_PATTERN)
RESERVED = frozenset(
    "F G X U T true false not and or implies eventually always next until then "
    "abs sqrt exp log min max "
    "inf Inf infinity nan NaN".split()  # not numbers here (a bound must be finite), and no signal's name either
)
FUNCTIONS = {"abs": 1, "sqrt": 1, "exp": 1, "log": 1, "min": -1, "max": -1}
COMPARISONS = ("<", "<=", ">", ">=")
ARITHMETIC_OPERATORS = ("+", "-", "*", "/", "^")

# Printing precedence of expressions, loosest first.
_E_ADD, _E_MUL, _E_UNARY, _E_POW, _E_ATOM = 1, 2, 3, 4, 5
# Printing precedence of formulas, loosest first.
_F_IMPLIES, _F_OR, _F_AND, _F_BINARY_TEMPORAL, _F_UNARY, _F_ATOM = 1, 2, 3, 4, 5, 6


def _wrapped(child: Any, needed: int) -> list[Any]:
    """Print pieces of ``child``, in parentheses when it binds looser than ``needed``."""
    return ["(", child, ")"] if child.precedence < needed else [child]


def _render(root: Any) -> str:
    """The canonical text of a node, from the pieces its ``_pieces`` lists (strings and nodes).

    One explicit stack instead of nested ``str`` calls: linear in the text's length at any depth.
    """
    out: list[str] = []
    stack: list[Any] = [root]
    while stack:
        item = stack.pop()
        if isinstance(item, str):
            out.append(item)
        else:
            stack.extend(reversed(item._pieces()))
    return "".join(out)


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
        stack: list[Expr] = [self]
        while stack:
            expr = stack.pop()
            if isinstance(expr, Var):
                names.setdefault(expr.name, None)
            stack.extend(reversed(parts(expr)))
        return tuple(names)

    def __str__(self) -> str:
        return _render(self)

    def _pieces(self) -> list[Any]:
        return [repr(self)]  # a node class from elsewhere, with no syntax of its own


ExprLike = Union[Expr, int, float]


@dataclass(frozen=True, eq=True)
class Var(Expr):
    """A signal read from the trace, by name."""

    name: str

    def __post_init__(self) -> None:
        # the parser's identifiers (letters, digits, underscores), so that every formula prints as text that parses
        if not (self.name.isidentifier() and _SIGNAL_NAME.fullmatch(self.name)) or self.name in RESERVED:
            raise ValueError(f"{self.name!r} cannot name a signal (reserved or not an identifier)")

    def _pieces(self) -> list[Any]:
        return [self.name]


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

    def _pieces(self) -> list[Any]:
        v = self.value
        if v.is_integer() and abs(v) < 1e16:
            return [str(int(v))]
        return [repr(v)]


@dataclass(frozen=True, eq=True)
class Neg(Expr):
    """Unary minus."""

    operand: Expr
    precedence: ClassVar[int] = _E_UNARY

    def _pieces(self) -> list[Any]:
        if isinstance(self.operand, Num) and self.operand.precedence == _E_ATOM:
            return ["-(", self.operand, ")"]  # keep `-3` for Num(-3): a literal folds into the number
        space = " " if _starts_with_minus(self.operand) else ""
        return ["-" + space, *_wrapped(self.operand, _E_UNARY)]


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

    def _left_needs(self) -> int:
        """The precedence the left operand must have to print without parentheses."""
        return _E_ATOM if self.op == "^" else self.precedence

    def _pieces(self) -> list[Any]:
        if self.op == "^":  # right-associative; the exponent may carry a unary minus
            right_needs = _E_UNARY
        else:  # left-associative
            right_needs = self.precedence + 1
        return [*_wrapped(self.left, self._left_needs()), f" {self.op} ", *_wrapped(self.right, right_needs)]


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

    def _pieces(self) -> list[Any]:
        pieces: list[Any] = [f"{self.func}("]
        for i, arg in enumerate(self.args):
            pieces += [", ", arg] if i else [arg]
        return [*pieces, ")"]


def as_expr(value: ExprLike) -> Expr:
    """Turn a Python number into a `Num` (negative numbers fold into the literal)."""
    if isinstance(value, Expr):
        return value
    # numbers.Real admits numpy's scalars (``x > goal[0]`` of a float32 array), not only int and float
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"expected an expression or a number, got {type(value).__name__}: {value!r}")
    return Num(float(value))


def _starts_with_minus(expr: Expr) -> bool:
    """Whether ``str(expr)`` starts with ``-``, found down the left edge without printing it."""
    while True:
        if isinstance(expr, Num):
            return expr._pieces()[0].startswith("-")
        if isinstance(expr, Neg):
            return True
        if not isinstance(expr, BinOp) or expr.left.precedence < expr._left_needs():
            return False  # a name, a call, or a parenthesised left operand
        expr = expr.left


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
        return _derived(self, "_signals", _signals_of)

    def walk(self) -> list[Formula]:
        """Every node of the formula, parents before children (pre-order)."""
        out: list[Formula] = []
        stack: list[Formula] = [self]
        while stack:
            node = stack.pop()
            out.append(node)
            stack.extend(reversed(node.children))
        return out

    @property
    def is_temporal(self) -> bool:
        """Whether any temporal operator occurs in the formula."""
        return _derived(self, "_temporal", _temporal_of)

    @property
    def depth(self) -> int:
        """Nesting depth of the formula's operators (1 for a predicate or constant; arithmetic not counted)."""
        return _derived(self, "_depth", _depth_of)

    def __str__(self) -> str:
        return _render(self)

    def _pieces(self) -> list[Any]:
        return [repr(self)]  # a node class from elsewhere, with no syntax of its own

    # Semantics (the evaluators live in their own modules) ---------------------------
    def robustness(self, trace: Trace, rho_max: float = math.inf, backend: str = "auto") -> float | np.ndarray:
        """Robustness of the trace at position 0 (> 0 means it satisfies the formula).

        Args:
            trace: maps each signal name to an array of shape ``(T,)`` or ``(N, T)``;
                extra names are ignored.
            rho_max: the value of ``true`` (and minus that of ``false`` and of ``X φ``
                at the last state).
            backend: ``"numba"``: one fused loop compiled for this formula (`tl_gym.tltl.fused`,
                needs the ``tl_gym[fast]`` extra; formulas it does not cover, or a missing numba,
                use numpy); ``"numpy"``: the numpy plan; ``"auto"`` (the default): the numpy plan
                until the compiled loop pays (`fused.auto_robustness`: numba is installed and the
                kernel was compiled on this machine before, or the formula has cost this process
                half a second), then the loop. The values are the same (bit for bit, except that
                ``exp``, ``log`` and general powers may differ in the last bit).

        Returns:
            A float for ``(T,)`` signals, an array of shape ``(N,)`` for ``(N, T)``.

        Raises:
            UnknownSignalError: the trace lacks a signal the formula reads.
            TraceError: signals of different shapes, no state, more than two axes, a NaN or infinite value
                (naming the signal and position), or a predicate's arithmetic undefined on the trace.
            ValueError: an unknown ``backend``, or ``rho_max`` ≤ 0.

        Every other evaluation method of a formula raises the same on the same input.
        """
        from tl_gym.tltl import exact, fused
        from tl_gym.tltl.trace import check_backend

        if check_backend(backend) == "numba":
            return fused.robustness(self, trace, rho_max)
        if backend == "auto":
            return fused.auto_robustness(self, trace, rho_max)
        return exact.robustness(self, trace, rho_max)

    def robustness_over_time(self, trace: Trace, rho_max: float = math.inf) -> np.ndarray:
        """Robustness of every suffix: entry ``t`` judges the states ``t … T-1``.

        Returns an array of shape ``(T,)`` or ``(N, T)``; entry 0 is `robustness`. Raises as `robustness`.
        """
        from tl_gym.tltl import exact

        return exact.robustness_over_time(self, trace, rho_max)

    def satisfied(self, trace: Trace) -> bool | np.ndarray:
        """Boolean semantics at position 0: a bool, or a bool array of shape ``(N,)``. Raises as `robustness`."""
        from tl_gym.tltl import exact

        return exact.satisfied(self, trace)

    def smooth_robustness(self, trace: Trace, beta: float, rho_max: float = math.inf, form: str = "nested",
                          backend: str = "auto") -> Any:
        """Log-sum-exp smoothed robustness with sharpness ``beta`` (paper, section V).

        Every max and min of the definition, the ones over time included, becomes
        ``±log(Σ exp(±β x))/β``, nested as the definition nests. Given torch tensors
        the result is a torch tensor differentiable by autograd; given numpy arrays, a
        float or an ``(N,)`` array (computed in float64). ``form="linear"`` trades the
        prescribed O(T²) nesting of a ``T`` under another temporal operator for an
        O(T) smoothing with the same limit and bracket (see `tl_gym.tltl.smooth`).
        ``backend="auto"`` (the default) computes it with a kernel compiled once per machine
        when numba is installed (``tl_gym[fast]``; `tl_gym.tltl.fused_smooth`, equal to the
        numpy plan to rounding) once the process has spent a second smoothing with numpy, else
        with the numpy plan; ``"numba"`` uses the kernel at once, ``"numpy"`` never.

        Raises as `robustness`, and ``ValueError`` for ``beta`` ≤ 0 or an unknown ``form``; a `TraceError` for a
        predicate value too large to smooth (``|β · value|`` overflows), naming it.
        """
        from tl_gym.tltl import smooth

        return smooth.smooth_robustness(self, trace, beta, rho_max, form, backend)

    def smooth_robustness_and_gradient(self, trace: Trace, beta: float, rho_max: float = math.inf,
                                       form: str = "nested", backend: str = "auto") -> tuple[Any, dict[str, Any]]:
        """`smooth_robustness` of numpy signals and its gradient, without autograd.

        Returns ``(values, gradients)``: the values as `smooth_robustness` gives them (a float,
        or ``(N,)`` for a batch) and, per signal the formula reads, the gradient of each value
        with respect to its own trajectory (the signal's shape; zero where a value is ±∞). The
        same numbers as torch's autograd through `smooth_robustness` (tested), without a
        tensor round trip: about 10 % faster on the car's task-2 batch of 40 × 201 steps, where
        TLPS's trust region asks for it 21 times an iteration (``python -m benchmarks.bench_gradient``).

        Example:
            >>> import numpy as np
            >>> from tl_gym import parse
            >>> value, grad = parse("F(s > 5)").smooth_robustness_and_gradient({"s": np.array([1.0, 6.0])}, 9.0)
            >>> round(value, 4), np.round(grad["s"], 4).tolist()
            (1.0, [0.0, 1.0])
        """
        from tl_gym.tltl import smooth

        return smooth.smooth_robustness_and_gradient(self, trace, beta, rho_max, form, backend)

    def smooth_robustness_over_time(
        self, trace: Trace, beta: float, rho_max: float = math.inf, form: str = "nested"
    ) -> Any:
        """Smoothed robustness of every suffix, ``(T,)`` or ``(N, T)``: a torch tensor for torch input, else numpy."""
        from tl_gym.tltl import smooth

        return smooth.smooth_over_time(self, trace, beta, rho_max, form)

    def smoothing_bracket(self, horizon: int, beta: float) -> tuple[float, float]:
        """Bounds ``(below, above)`` with ``ρ - below ≤ ρ̂ ≤ ρ + above`` (paper, Lemma 1).

        Each max node of ``n`` terms adds ``log(n)/β`` above, each min node
        ``log(n)/β`` below, taken along the worst path, for traces of length ``horizon``.

        Raises:
            ValueError: ``horizon`` < 1 or ``beta`` ≤ 0.
        """
        from tl_gym.tltl import bracket

        return bracket.smoothing_bracket(self, horizon, beta)


def _as_formula(value: Any) -> Formula:
    if isinstance(value, Formula):
        return value
    if isinstance(value, bool):
        return Constant(value)
    hint = " (compare it to make a predicate, e.g. `x > 0`)" if isinstance(value, Expr) else ""
    raise TypeError(f"expected a Formula, got {type(value).__name__}: {value!r}{hint}")


def _check_children(node: Formula) -> None:
    """Refuse a child that is not a formula at construction (``F(x)`` of a bare signal, ``G("x > 1")``).

    Such a tree printed as text that does not parse and failed only when evaluated, with an
    AttributeError; a Python bool becomes `Constant`, as ``&`` and ``|`` already make it.
    """
    for field in ("child", "left", "right"):
        value = node.__dict__.get(field, _MISSING)
        if value is not _MISSING and not isinstance(value, Formula):
            object.__setattr__(node, field, _as_formula(value))


def _derived(node: Formula, attribute: str, rule: Callable[[Formula, list[Any]], Any]) -> Any:
    """A property of ``node`` computed from its children's by ``rule``, bottom-up, kept on each node."""
    cached = node.__dict__.get(attribute, _MISSING)
    if cached is not _MISSING:
        return cached
    for item in _postorder_missing(node, attribute, lambda n: n.children):
        object.__setattr__(item, attribute, rule(item, [c.__dict__[attribute] for c in item.children]))
    return node.__dict__[attribute]


def _signals_of(node: Formula, children: list[tuple[str, ...]]) -> tuple[str, ...]:
    if isinstance(node, Predicate):
        return tuple(dict.fromkeys(node.lhs.signal_names() + node.rhs.signal_names()))
    if len(children) == 1:
        return children[0]
    return tuple(dict.fromkeys(name for names in children for name in names))


def _temporal_of(node: Formula, children: list[bool]) -> bool:
    return isinstance(node, (Next, Eventually, Always, Until, Then)) or any(children)


def _depth_of(node: Formula, children: list[int]) -> int:
    return 1 + max(children, default=0)


@dataclass(frozen=True, eq=True)
class Constant(Formula):
    """``true`` (robustness ρ_max) or ``false`` (−ρ_max)."""

    value: bool

    def _pieces(self) -> list[Any]:
        return ["true" if self.value else "false"]


@dataclass(frozen=True, eq=True)
class Predicate(Formula):
    """``lhs op rhs``: ``a < b`` and ``a <= b`` have robustness ``b - a``; ``>``, ``>=`` have ``a - b``."""

    lhs: Expr
    op: str
    rhs: Expr

    def __post_init__(self) -> None:
        if self.op not in COMPARISONS:
            raise ValueError(f"unknown comparison {self.op!r}; use one of {COMPARISONS}")
        if not (isinstance(self.lhs, Expr) and isinstance(self.rhs, Expr)):  # a number becomes a Num
            object.__setattr__(self, "lhs", as_expr(self.lhs))
            object.__setattr__(self, "rhs", as_expr(self.rhs))

    def _pieces(self) -> list[Any]:
        return [self.lhs, f" {self.op} ", self.rhs]


@dataclass(frozen=True, eq=True)
class Not(Formula):
    """Negation: robustness ``-ρ(φ)``."""

    child: Formula
    precedence: ClassVar[int] = _F_UNARY

    def __post_init__(self) -> None:
        _check_children(self)

    @property
    def children(self) -> tuple[Formula, ...]:
        return (self.child,)

    def _pieces(self) -> list[Any]:
        return ["!", *_wrapped(self.child, _F_UNARY)]


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

    def _pieces(self) -> list[Any]:
        pieces: list[Any] = []
        for i, child in enumerate(self.children):
            if i:
                pieces.append(f" {self.symbol} ")
            pieces += _wrapped(child, self.precedence + 1)
        return pieces


@dataclass(frozen=True, eq=True)
class And(_NAry):
    """Conjunction of two or more formulas: one n-ary min."""

    operands: tuple[Formula, ...]
    symbol: ClassVar[str] = "&"
    precedence: ClassVar[int] = _F_AND


def conjuncts(formula: Formula) -> tuple[Formula, ...]:
    """The top-level conjuncts: the operands of an n-ary ``&``, else the formula alone."""
    return formula.operands if isinstance(formula, And) else (formula,)


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

    def __post_init__(self) -> None:
        _check_children(self)

    @property
    def children(self) -> tuple[Formula, ...]:
        return (self.left, self.right)

    def _pieces(self) -> list[Any]:
        own = self.precedence
        return [*_wrapped(self.left, own + 1), f" {self.symbol} ", *_wrapped(self.right, own)]


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

    def __post_init__(self) -> None:
        _check_children(self)

    @property
    def children(self) -> tuple[Formula, ...]:
        return (self.child,)

    def _pieces(self) -> list[Any]:
        return [f"{self.symbol} ", *_wrapped(self.child, _F_UNARY)]


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


_MISSING = object()


def parts(node: Any) -> tuple[Any, ...]:
    """A node's direct sub-nodes, formulas and expressions alike (a predicate's are its two sides)."""
    if isinstance(node, Formula):
        return (node.lhs, node.rhs) if isinstance(node, Predicate) else node.children
    if isinstance(node, Neg):
        return (node.operand,)
    if isinstance(node, BinOp):
        return (node.left, node.right)
    if isinstance(node, Call):
        return node.args
    return ()


def _postorder_missing(root: Any, attribute: str, children: Callable[[Any], tuple[Any, ...]]) -> list[Any]:
    """The nodes under ``root`` that lack ``attribute``, children before parents, each once.

    Nodes that have it are not entered: what is cached below them is already complete.
    """
    order: list[Any] = []
    seen: set[int] = set()
    stack: list[tuple[Any, bool]] = [(root, False)]
    while stack:
        node, expanded = stack.pop()
        if expanded:
            order.append(node)
            continue
        if id(node) in seen or attribute in node.__dict__:
            continue
        seen.add(id(node))
        stack.append((node, True))
        stack.extend((child, False) for child in reversed(children(node)))
    return order


_FIELDS: dict[type, tuple[str, ...]] = {}  # each node class's dataclass fields (not its ClassVars), in order


def _fields(cls: type) -> tuple[str, ...]:
    """The dataclass fields of a node class (none for a class that is not a dataclass)."""
    names = _FIELDS.get(cls)
    if names is None:
        names = _FIELDS[cls] = tuple(f.name for f in dataclasses.fields(cls)) if dataclasses.is_dataclass(cls) else ()
    return names


def _cached_hash(self: Any) -> int:
    """Structural hash, computed once per node (bottom-up, no recursion): evaluators key their caches by node."""
    cached = self.__dict__.get("_hash")
    if cached is not None:
        return cached
    for node in _postorder_missing(self, "_hash", parts):
        fields = _fields(type(node))
        object.__setattr__(node, "_hash", hash((type(node).__name__, *(getattr(node, f) for f in fields))))
    return self.__dict__["_hash"]


_SHALLOW = 200  # nodes up to this height compare by plain recursion: bounded, and faster than a stack
_GETTERS: dict[type, Callable[[Any], Any]] = {}


def height(node: Any) -> int:
    """Height of the node's tree, expressions included (1 for a leaf); kept on each node."""
    cached = node.__dict__.get("_height")
    if cached is not None:
        return cached
    for item in _postorder_missing(node, "_height", parts):
        object.__setattr__(item, "_height", 1 + max((c.__dict__["_height"] for c in parts(item)), default=0))
    return node.__dict__["_height"]


def _structural_eq(self: Any, other: Any) -> Any:
    """Structural equality, as the dataclasses define it (field by field), at any depth."""
    if self is other:
        return True
    if type(other) is not type(self):
        return NotImplemented
    hash_a, hash_b = self.__dict__.get("_hash"), other.__dict__.get("_hash")
    if hash_a is not None and hash_b is not None and hash_a != hash_b:
        return False
    if height(self) <= _SHALLOW:
        getter = _GETTERS.get(type(self))
        if getter is None:
            names = _fields(type(self))
            getter = _GETTERS[type(self)] = operator.attrgetter(*names) if names else (lambda node: ())
        return getter(self) == getter(other)  # the fields' own __eq__: recursion no deeper than _SHALLOW
    return _deep_eq(self, other)


def _deep_eq(self: Any, other: Any) -> bool:
    """Structural equality compared pair by pair on an explicit stack."""
    stack: list[tuple[Any, Any]] = [(self, other)]
    while stack:
        a, b = stack.pop()
        if a is b:
            continue
        if type(a) is not type(b):
            return False
        hash_a, hash_b = a.__dict__.get("_hash"), b.__dict__.get("_hash")
        if hash_a is not None and hash_b is not None and hash_a != hash_b:
            return False
        for field in _fields(type(a)):
            x, y = getattr(a, field), getattr(b, field)
            if isinstance(x, tuple):
                if not isinstance(y, tuple) or len(x) != len(y):
                    return False
                stack.extend(zip(x, y))
            elif isinstance(x, (Formula, Expr)):
                stack.append((x, y))
            elif type(x) is not type(y) or x != y:
                return False
    return True


def _repr(self: Any) -> str:
    """``Class(field=value, ...)`` as the dataclasses print it, from an explicit stack."""
    out: list[str] = []
    stack: list[Any] = [self]
    while stack:
        item = stack.pop()
        if isinstance(item, str):
            out.append(item)
            continue
        pieces: list[Any] = [f"{type(item).__name__}("]
        for i, field in enumerate(_fields(type(item))):
            pieces.append(f"{', ' if i else ''}{field}=")
            value = getattr(item, field)
            if isinstance(value, tuple):
                pieces.append("(")
                for j, element in enumerate(value):
                    pieces += [", ", element] if j else [element]
                pieces.append(",)" if len(value) == 1 else ")")
            elif isinstance(value, (Formula, Expr)):
                pieces.append(value)
            else:
                pieces.append(repr(value))
        pieces.append(")")
        stack.extend(reversed(pieces))
    return "".join(out)


def _state_without_caches(self: Any) -> dict[str, Any]:
    """Pickle state without the cached values: string hashes differ between processes."""
    return {k: v for k, v in self.__dict__.items() if not k.startswith("_")}


_PICKLE_HEIGHT = 40  # pickle and deepcopy recurse several frames per level: deeper trees go through their text


def _reduce(self: Any) -> tuple[Any, ...]:
    """Pickle (and deepcopy) support at any depth: a deep tree is rebuilt by parsing its canonical text."""
    if height(self) > _PICKLE_HEIGHT:
        return (_from_text, (isinstance(self, Formula), str(self)))
    return (copyreg.__newobj__, (type(self),), _state_without_caches(self))


def _from_text(is_formula: bool, text: str) -> Any:
    from tl_gym.tltl.parser import parse

    return parse(text) if is_formula else parse(f"{text} > 0").lhs  # type: ignore[attr-defined]


for _cls in (*FORMULA_NODES, Var, Num, Neg, BinOp, Call):
    _cls.__hash__ = _cached_hash  # type: ignore[method-assign]
    _cls.__eq__ = _structural_eq  # type: ignore[method-assign]
    _cls.__repr__ = _repr  # type: ignore[method-assign]
    _cls.__getstate__ = _state_without_caches  # type: ignore[attr-defined]
    _cls.__reduce__ = _reduce  # type: ignore[method-assign]
