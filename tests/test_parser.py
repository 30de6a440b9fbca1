"""The parser: round trip, spellings, the precedence table of issue 3, errors with a caret, fuzzing."""

from __future__ import annotations

import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from tests import strategies as S
from tl_gym import SpecError, parse
from tl_gym.logic import (
    FALSE,
    TRUE,
    F,
    G,
    T,
    U,
    X,
    all_of,
    any_of,
    exp,
    implies,
    log,
    maximum,
    minimum,
    not_,
    signal,
    signals,
    sqrt,
)
from tl_gym.tltl.ast import BinOp, Constant, Neg, Num, Predicate, Var

x, y, z = signals("x y z")
p, q, r = x > 1, y < 2, z >= 0

# --------------------------------------------------------------------------- round trip


def _round_trips(formula) -> None:
    text = str(formula)
    again = parse(text)
    assert again == formula, f"{text!r} parsed to {again!r}"
    assert str(again) == text


@given(S.formulas(S.TRICKY_NAMES, max_depth=5, leaves=S.predicates(S.TRICKY_NAMES, S.expressions(S.TRICKY_NAMES))))
def test_round_trip_hypothesis(formula):
    _round_trips(formula)


BUILT = [
    F((x > 5) & (x < 10)),
    G(abs(y) < 1),
    F((x > 5) & (x < 10)) & G(abs(y) < 1),
    U(~(p | q), r),
    T(p, T(q, r)),
    T(T(p, q), r),
    U(U(p, q), r),
    X(X(p)),
    implies(p, implies(q, r)),
    implies(implies(p, q), r),
    p >> (q >> r),
    not_(p & q),
    ~~p,
    ~F(p),
    F(~p),
    all_of(p, q, r) | all_of(q, r),
    any_of(p, q) & any_of(q, r),
    F(G(p)) & G(F(q)),
    U(F(p), G(q)),
    T(X(p), q | r),
    TRUE & p,
    FALSE | ~TRUE,
    sqrt((x - 0.5) ** 2 + (y - 0.5) ** 2) > 0.2,
    exp(-x) + log(1 + abs(y)) < minimum(x, y, 3) * maximum(z, -2),
    x > -3,
    -x > 3,
    -(x - y) < z,
    x * -2.5 <= y / -0.5,
    2 - x >= 1e-300,
    x ** -2 < 1.5e300,
    x ** (y ** z) < 2,
    (x ** y) ** z < 2,
    x - (y - z) < 0,
    (x - y) - z < 0,
    x / (y * z) < 1,
    Neg(Neg(x)) < 1,
    Predicate(Neg(Num(3.0)), "<", x),
    Predicate(Neg(Num(-3.0)), "<", x),
    Predicate(BinOp("^", Num(-2.0), x), "<", Neg(BinOp("^", Num(2.0), x))),
    Predicate(BinOp("^", x, BinOp("^", Num(-2.0), Num(3.0))), ">", Num(0.1)),
]


@pytest.mark.parametrize("formula", BUILT, ids=[str(f) for f in BUILT])
def test_round_trip_builders(formula):
    _round_trips(formula)


def test_builders_make_what_the_parser_makes():
    assert parse("F(x > 5 & x < 10)") == F((x > 5) & (x < 10))
    assert parse("x > -3") == Predicate(Var("x"), ">", Num(-3.0))
    assert parse("x ** 2 < 1") == Predicate(BinOp("^", Var("x"), Num(2.0)), "<", Num(1.0))
    assert parse("true & false") == Constant(True) & Constant(False)
    assert parse("x < 1 U (y < 2 T z < 3)") == U(x < 1, T(y < 2, z < 3))
    assert signal("x") == Var("x")


# --------------------------------------------------------------------------- spellings

SPELLINGS = [
    ("x > 1 & y < 2", ["x > 1 && y < 2", "x > 1 and y < 2", "(x > 1) & (y < 2)"]),
    ("x > 1 | y < 2", ["x > 1 || y < 2", "x > 1 or y < 2"]),
    ("x > 1 -> y < 2", ["x > 1 => y < 2", "x > 1 implies y < 2"]),
    ("!(x > 1)", ["not x > 1", "! x > 1", "not (x > 1)"]),
    ("F x > 1", ["eventually x > 1", "eventually(x > 1)", "F(x > 1)"]),
    ("G x > 1", ["always x > 1", "always (x > 1)"]),
    ("X x > 1", ["next x > 1", "next(x > 1)"]),
    ("x > 1 U y < 2", ["x > 1 until y < 2"]),
    ("x > 1 T y < 2", ["x > 1 then y < 2"]),
    ("x ^ 2 < 1", ["x ** 2 < 1", "x**2<1", "(x)^(2) < (1)"]),
    ("x >= 1e3", ["x >= 1000", "x >= 1000.0", "x >= 1E+3", "x>=1000."]),
    ("x < 0.5", ["x < .5", "x < 5e-1", "x<0.50"]),
    (
        "always (x > 1 implies eventually y < 2) and not next z >= 0",
        ["G (x > 1 -> F y < 2) & !X z >= 0", "G(x>1=>F y<2)&&!X z>=0"],
    ),
]


@pytest.mark.parametrize(("canonical", "variants"), SPELLINGS, ids=[c for c, _ in SPELLINGS])
def test_keyword_and_alias_spellings(canonical, variants):
    expected = parse(canonical)
    for text in variants:
        assert parse(text) == expected, text


# --------------------------------------------------------------------------- precedence

PRECEDENCE = [
    # arithmetic binds tighter than comparison
    ("x + 1 < 2 * y", x + 1 < 2 * y),
    ("x - y - z < 0", (x - y) - z < 0),
    ("x / y * z < 0", (x / y) * z < 0),
    ("x + y * z < 0", x + (y * z) < 0),
    ("x ^ 2 ^ 3 < 0", x ** (Num(2.0) ** Num(3.0)) < 0),
    ("- x ^ 2 < 1", Neg(x ** 2) < 1),
    ("-x * y < 1", Neg(x) * y < 1),
    ("-3 ^ 2 < x", Neg(Num(3.0) ** 2) < x),
    # comparison binds tighter than the unary operators
    ("! x > 1", ~(x > 1)),
    ("F x > 1", F(x > 1)),
    ("X X x > 1", X(X(x > 1))),
    ("F G x > 1", F(G(x > 1))),
    # unary binds tighter than U/T
    ("F x > 1 U y < 2", U(F(x > 1), y < 2)),
    ("! x > 1 T y < 2", T(~(x > 1), y < 2)),
    ("x > 1 U G y < 2", U(x > 1, G(y < 2))),
    # U/T are right-associative
    ("x > 1 U y < 2 U z >= 0", U(p, U(q, r))),
    ("x > 1 T y < 2 T z >= 0", T(p, T(q, r))),
    ("x > 1 U y < 2 T z >= 0", U(p, T(q, r))),
    ("x > 1 T y < 2 U z >= 0", T(p, U(q, r))),
    # U/T bind tighter than &
    ("x > 1 U y < 2 & z >= 0", U(p, q) & r),
    ("x > 1 & y < 2 T z >= 0", p & T(q, r)),
    # & binds tighter than |
    ("x > 1 & y < 2 | z >= 0", (p & q) | r),
    ("x > 1 | y < 2 & z >= 0", p | (q & r)),
    # | binds tighter than ->
    ("x > 1 | y < 2 -> z >= 0", implies(p | q, r)),
    ("x > 1 -> y < 2 | z >= 0", implies(p, q | r)),
    ("x > 1 & y < 2 -> z >= 0", implies(p & q, r)),
    # -> is right-associative
    ("x > 1 -> y < 2 -> z >= 0", implies(p, implies(q, r))),
    # n-ary chains
    ("x > 1 & y < 2 & z >= 0", all_of(p, q, r)),
    ("x > 1 | y < 2 | z >= 0", any_of(p, q, r)),
    # everything at once
    ("! F x > 1 U y < 2 & z >= 0 | x > 1 -> y < 2", implies((U(~F(p), q) & r) | p, q)),
]


@pytest.mark.parametrize(("text", "expected"), PRECEDENCE, ids=[t for t, _ in PRECEDENCE])
def test_precedence(text, expected):
    assert parse(text) == expected


def test_signal_names_may_start_like_keywords():
    formula = parse("Fx > 1 & nota < 2 & Until >= 0 & always_ < 3 & X_ > 0 & trueish < 1")
    assert formula.signals == ("Fx", "nota", "Until", "always_", "X_", "trueish")


# --------------------------------------------------------------------------- errors

MALFORMED = [
    # text, 1-based column of the culprit
    ("", 1),
    ("   ", 4),
    ("x <", 4),
    ("x < 1 &", 8),
    ("x < 1 & & y > 2", 9),
    ("(x < 1", 7),
    ("x < 1)", 6),
    ("(x < 1))", 8),
    ("x < (1", 7),
    ("F(x < 1", 8),
    ("x < 1 < 2", 7),
    ("x", 2),
    ("x + < 1", 5),
    ("x ^ < 2", 5),
    ("F", 2),
    ("!", 2),
    ("not", 4),
    ("always", 7),
    ("G)", 2),
    ("x < 1 U", 8),
    ("U x < 1", 1),
    ("x < 1 U U y > 1", 9),
    ("x < 1 $ y", 7),
    ("x < 1 # comment", 7),
    ("x ≠ 1", 3),
    ("x <= = 1", 6),
    ("x + F < 1", 5),
    ("x < until", 5),
    ("sqrt(x, y) < 1", 1),
    ("foo(x) < 1", 1),  # an unknown function, not a signal followed by '('
    ("abs x < 1", 5),
    ("min() < 1", 5),
    ("x < 1e999", 5),
    ("x > -1e999", 6),  # a negative literal is folded into one number: checked the same
    ("x > -1.8e308", 6),
    ("x < 1 -> ", 10),
    ("x < 1 =>", 9),
    ("x < 1 && || y > 1", 10),
    ("x < 1 and or y > 2", 11),
    ("1.2.3 < x", 4),
    ("2x < 1", 2),
    ("x < 1 y > 2", 7),
    ("x < 1 & (y > 2 | z < 3", 23),
]


@pytest.mark.parametrize(("text", "column"), MALFORMED, ids=[repr(t) for t, _ in MALFORMED])
def test_malformed_input_raises_spec_error_with_caret(text, column):
    with pytest.raises(SpecError) as info:
        parse(text)
    error = info.value
    assert isinstance(error, ValueError)
    assert error.column == column, f"column {error.column}, expected {column}: {error}"
    lines = str(error).split("\n")
    assert f"(column {column})" in lines[0]
    assert lines[1] == "    " + text
    assert lines[2] == "    " + " " * (column - 1) + "^"


def test_malformed_messages_name_the_problem():
    def message(text: str) -> str:
        with pytest.raises(SpecError) as info:
            parse(text)
        return str(info.value).split("\n")[0]

    assert "empty" in message("")
    assert "'$'" in message("x < 1 $ y")
    assert "chain" in message("x < 1 < 2")
    assert "')'" in message("(x < 1")
    assert "'until' is a temporal operator and cannot name a signal" in message("x < until")
    assert "sqrt" in message("sqrt(x, y) < 1")
    assert "foo" in message("foo(x) < 1")


RESERVED_AS_NAMES = [
    # text, the word reported, its column: a word of the syntax used as a signal name
    ("F > 10", "'F' is a temporal operator", 1),
    ("x > 0 & G <= 1", "'G' is a temporal operator", 9),
    ("X ^ 2 > 0", "'X' is a temporal operator", 1),
    ("U > 0", "'U' is a temporal operator", 1),
    ("x > 0 & T < 5", "'T' is a temporal operator", 9),
    ("next + 1 > 0", "'next' is a temporal operator", 1),
    ("then >= 3", "'then' is a temporal operator", 1),
    ("not > 0", "'not' is reserved", 1),
    ("x > 0 | and < 1", "'and' is reserved", 9),
    ("true > 1", "'true' is a constant", 1),
    ("x > 0 & false * 2 > 1", "'false' is a constant", 9),
]


@pytest.mark.parametrize(("text", "message", "column"), RESERVED_AS_NAMES, ids=[t for t, _, _ in RESERVED_AS_NAMES])
def test_a_reserved_word_used_as_a_signal_name_is_named(text, message, column):
    """`F > 10` (a force F) said "expected a predicate ... found '>'", pointing past the culprit."""
    with pytest.raises(SpecError, match=message + " and cannot name a signal") as info:
        parse(text)
    assert info.value.column == column


def test_caret_of_a_multi_line_formula_is_under_the_token():
    """A triple-quoted formula: the caret stood under the first line at the offset in the whole text."""
    text = "F(x > 1\n  & y < 2\n  & )"
    with pytest.raises(SpecError) as info:
        parse(text)
    error = info.value
    assert (error.line, error.column) == (3, 5)
    lines = str(error).split("\n")
    assert "(line 3, column 5)" in lines[0]
    assert lines[1:] == ["      & )", "        ^"]


def test_caret_after_a_tab_keeps_the_tab():
    """A tab before the culprit is shown as wide as the tab in the quoted text, so the caret lines up."""
    with pytest.raises(SpecError) as info:
        parse("x >\t1 & )")
    assert str(info.value).split("\n")[1:] == ["    x >\t1 & )", "       \t    ^"]


def test_numbers_may_group_digits_with_underscores():
    """As in Python: `1_000` was read as 1 followed by a stray `_000`."""
    assert parse("x > 1_000") == parse("x > 1000")
    assert parse("x < 1_000.000_5e1_0") == parse("x < 1000.0005e10")
    assert parse("x > _1").signals == ("x", "_1")  # a leading underscore is still a name
    for bad in ("x > 1__0", "x > 1_"):
        with pytest.raises(SpecError):
            parse(bad)


def test_any_name_a_signal_may_have_parses_back():
    """`signal("θ")` is a valid name, but the parser read only ASCII names: `parse(str(F(θ > 1)))` failed,
    and so did pickling or deep-copying a formula deeper than 40 levels (rebuilt from its text)."""
    import pickle

    theta = signal("θ")
    _round_trips(F(theta > 1) & G(signal("vélocité") < 2))
    deep = theta > 0
    for _ in range(50):
        deep = F(deep)
    assert pickle.loads(pickle.dumps(deep)) == deep
    with pytest.raises(SpecError, match="'x²' cannot name a signal"):
        parse("x² > 1")


@pytest.mark.parametrize("name", ["a·b", "x\u0301", "℘", "℮"])
def test_a_name_python_takes_but_the_parser_does_not_cannot_name_a_signal(name):
    """Python identifiers the tokenizer does not read: a formula on them would not print as text that parses."""
    assert name.isidentifier()
    with pytest.raises(ValueError, match="cannot name a signal"):
        signal(name)


def test_parse_takes_text_only():
    with pytest.raises(TypeError, match="string"):
        parse(3)  # type: ignore[arg-type]
    formula = parse("x < 1")
    assert parse(formula) is formula  # a Formula passes through


# --------------------------------------------------------------------------- fuzzing

ALPHABET = "xyz01.5e FGXUT!&|-><=()+*/^,a_ \tnotdlwsqrbpm[]{}~#□◇¬≤→"
TOKENS = [
    "x", "y", "1", "2.5", "-", "+", "*", "/", "^", "**", "(", ")", ",", "<", "<=", ">", ">=", "!", "&", "&&",
    "|", "||", "->", "=>", "F", "G", "X", "U", "T", "true", "false", "not", "and", "or", "implies", "eventually",
    "always", "next", "until", "then", "abs", "sqrt", "exp", "log", "min", "max",
]


def _parse_or_spec_error(text: str) -> None:
    try:
        formula = parse(text)
    except SpecError as error:
        assert 1 <= error.column <= len(text) + 1
        return
    _round_trips(formula)


@given(st.text(alphabet=ALPHABET, max_size=40))
@example("((((((((((x < 1))))))))))")
@example("x<1U!y>2TF(z<3)")
def test_fuzz_characters(text):
    _parse_or_spec_error(text)


@given(st.lists(st.sampled_from(TOKENS), max_size=15))
def test_fuzz_tokens(tokens):
    _parse_or_spec_error(" ".join(tokens))


FOREIGN = [  # another tool's syntax, and the words of the hint that says what to write here
    ("F[0,10](x > 1)", "bounded operators are not TLTL"),
    ("always[0:5](x > 0)", "bounded operators are not TLTL"),
    ("x > 0 U[0,3] y > 0", "bounded operators are not TLTL"),
    ("G_{[0,5]}(x > 0)", "bounded operators are not TLTL"),
    ("x > 0 <-> y > 0", r"TLTL has no iff \('<->'\): write \(a -> b\) & \(b -> a\)"),
    ("x > 0 iff y > 0", "TLTL has no iff or xor"),
    ("O(x > 0)", "past-time operators"),
    ("x > 0 since y > 0", "past-time operators"),
    ("finally (x > 0)", "'finally' is written F"),
    ("~(x > 0)", "negation is written !"),
    ("[](x > 0)", r"'\[\]' \(always\) is written G"),
    ("<>(x > 0)", r"'<>' \(eventually\) is written F"),
    ("x > 0 /\\ y > 0", r"\(and\) is written &"),
    ("x > 0 AND y > 0", "'and' is lowercase"),
    ("x > 0 R y > 0", "release and weak until are not TLTL operators"),
    ("GF x > 0", "operators are separate words: write G F"),
    ("FG(x > 0)", "operators are separate words: write F G"),
    ("x == 1", r"equality is not a TLTL comparison .*abs\(x - c\) < eps"),
    ("x != 0", r"write abs\(x - c\) > eps"),
    ("x =< 0", "did you mean '<='"),
    ("x => 1", "did you mean '>='"),
    ("x < inf", "a bound must be a finite number"),
    ("obs[0] > 1", r"signal names are identifiers .*signals=\{'obs_0': 0\}"),
    ("pos.x > 1", "signal names are identifiers"),
    ("x(t) > 0", r"a signal takes no argument: write x, not x\(t\)"),
    ("-(x > 0)", "negate a formula with !"),
    ("abs(x > 0)", "functions take arithmetic, not formulas"),
    ("T > 30", r"name it otherwise in signals= \(e.g. T_1\)"),
    ("!door_open", r"signals are real numbers, compared to make a predicate \(e.g. door_open > 0.5\)"),
    ("out = always(x > 0)", "write the formula alone, without 'name ='"),
    ("# comment", "without comments"),
    ("x // 2 > 1", "divide with /"),
    ("x <> 1", "not-equal is not a TLTL comparison"),
    ("x > 0 <=> y > 0", r"TLTL has no iff"),
    ("a > 0 ↔ b > 0", r"TLTL has no iff"),
    ("x ~= 1", "not-equal is not a TLTL comparison"),
    ("x < = 1", "did you mean '<='"),
    ("x ⇒ 1", "did you mean '>='"),
    ("inf > 1", r"name it otherwise in signals= \(e.g. inf_1\)"),
    ("x > NaN", "a comparison with NaN has no robustness"),
    ("X[0] > 1", "signal names are identifiers"),
    ("G(P)", "signals are real numbers"),  # a past-time letter that is a signal missing its comparison
    ("TRUE", "constants are lowercase"),
]


@pytest.mark.parametrize(("text", "hint"), FOREIGN, ids=[repr(t) for t, _ in FOREIGN])
def test_another_tools_syntax_is_refused_saying_what_to_write_instead(text, hint):
    with pytest.raises(SpecError, match=hint):
        parse(text)


def test_logic_notation_reads_as_the_ascii_operators_and_names_that_look_like_operators_stay_names():
    assert parse("□(x > 0 → ◇ y ≥ 1) ∧ ¬(z ≤ 2) ∨ ○ x > 1") == parse("G(x > 0 -> F y >= 1) & !(z <= 2) | X x > 1")
    assert parse("P > 3 & S < 1 & O >= 2").signals == ("P", "S", "O")  # past-time letters are names where valid
    assert str(parse("F(x > 0) & (y > 1)")) == "F x > 0 & y > 1"  # no chained-comparison message on valid text
    with pytest.raises(SpecError, match="comparisons do not chain"):
        parse("0 < x < 1")
    with pytest.raises(SpecError, match="unexpected '>' after a complete formula"):
        parse("F(x > 0) > 1")  # not a chain: the comparison follows a formula, not a predicate
