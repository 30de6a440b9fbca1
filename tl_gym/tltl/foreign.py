"""What other temporal-logic tools let you write, and what to write here instead: the parser's hints.

Users come from rtamt, stlcg++/stljax, STLGym, PSY-TaLiRo and LTL tools, whose syntax differs: bounded
operators (``F[0,10]``), past-time operators, ``==``, ``<->``, words such as ``finally``. The parser refuses
them, as TLTL has no such thing or spells it otherwise; these tables turn its refusal into a sentence
that says what to write. Consulted only on the error path: valid formulas never reach them.

Example:
    >>> from tl_gym import parse, SpecError
    >>> try:
    ...     parse("F[0,10](x > 1)")
    ... except SpecError as error:
    ...     print(str(error).splitlines()[0])
    unexpected character '[': bounded operators are not TLTL: F and G range over the rest of the episode, \
which the env's horizon bounds; drop the interval, or write a window with X (F[0,2] φ is φ | X φ | X X φ) (column 2)
"""

from __future__ import annotations

_BOUNDED = ("bounded operators are not TLTL: F and G range over the rest of the episode, which the env's horizon "
            "bounds; drop the interval, or write a window with X (F[0,2] φ is φ | X φ | X X φ)")
_PAST = ("past-time operators (once, historically, previous, since) are not TLTL, which looks forward from each "
         "state: record what you need as a signal, or state it forward (G, F, U)")
_EQUALITY = ("equality is not a TLTL comparison (robustness needs a margin): write abs(x - c) < eps, or "
             "x >= c & x <= c")
_INEQUALITY = "not-equal is not a TLTL comparison: write abs(x - c) > eps"
_IFF = "TLTL has no iff ('<->'): write (a -> b) & (b -> a)"
_NAMES = ("signal names are identifiers (letters, digits, _): give the entry a name in signals=, "
          "e.g. signals={'obs_0': 0} (or --signals obs_0=0)")

#: Character sequences of other tools, longest first, and what to write instead. The tokenizer checks the
#: ones that begin like an operator of this grammar (``<->`` like ``<``, ``!=`` like ``!``) before it reads
#: them as such (`preempted`); the others come up where it finds no token (`hint_at`).
SYMBOLS: tuple[tuple[str, str], ...] = (
    ("!==", _INEQUALITY),
    ("<->", _IFF),
    ("<=>", _IFF),
    ("[]", "'[]' (always) is written G"),
    ("<>", "'<>' (eventually) is written F"),
    ("==", _EQUALITY),
    ("!=", _INEQUALITY),
    ("=<", "did you mean '<='?"),
    ("//", "write the formula alone, without comments"),
    ("/\\", "'/\\' (and) is written &"),
    ("\\/", "'\\/' (or) is written |"),
    ("=", "write the formula alone, without 'name =' (and '==' is not a TLTL comparison: see abs(x - c) < eps)"),
    ("~=", _INEQUALITY),
    ("~", "negation is written ! (or not)"),
    ("↔", _IFF),
    ("⇔", _IFF),
    ("≠", _INEQUALITY),
    ("#", "write the formula alone, without comments"),
    (".", _NAMES),
    ("{", _BOUNDED),
)
_PREEMPTED = ("!==", "<->", "<=>", "<>", "==", "!=", "=<", "//", "/\\")
#: After an operand (a number, a name, ')'), these mean an operator between two numbers.
_BETWEEN_OPERANDS = {"<>": _INEQUALITY, "//": "'//' is not an operator: divide with / (x / 2)"}

#: Words other tools use as operators or constants, and what to write here. A word that names a signal
#: parses as one; these hints come up only where the parser fails at the word.
WORDS: dict[str, str] = {
    **dict.fromkeys(("iff", "equiv", "xor"),
                    "TLTL has no iff or xor: write (a -> b) & (b -> a), or (a & !b) | (!a & b)"),
    **dict.fromkeys(("since", "S", "once", "O", "P", "historically", "H", "prev", "previous", "Y", "pre"), _PAST),
    **dict.fromkeys(("release", "R", "unless", "W", "weak_until"),
                    "release and weak until are not TLTL operators: write them with U, G and ! "
                    "(a R b is !(!a U !b))"),
    "finally": "'finally' is written F (or eventually)",
    "globally": "'globally' is written G (or always)",
    "Always": "operators are lowercase or single capitals: G (or always)",
    "Eventually": "operators are lowercase or single capitals: F (or eventually)",
    **dict.fromkeys(("AND", "And"), "'and' is lowercase (or &)"),
    **dict.fromkeys(("OR", "Or"), "'or' is lowercase (or |)"),
    **dict.fromkeys(("NOT", "Not"), "'not' is lowercase (or !)"),
    **dict.fromkeys(("TRUE", "True"), "constants are lowercase: true, false"),
    **dict.fromkeys(("FALSE", "False"), "constants are lowercase: true, false"),
    **dict.fromkeys(("inf", "infinity"), "a bound must be a finite number: a predicate against infinity holds "
                                         "always or never; drop it, or use a large finite bound"),
    "nan": "a bound must be a number: a comparison with NaN has no robustness",
}

#: Other spellings of the operators that the tokenizer reads as this grammar's own (``□ x > 0`` is ``G x > 0``).
UNICODE_ALIASES: dict[str, str] = {
    "¬": "!", "∧": "&", "∨": "|", "→": "->", "⇒": "->", "≤": "<=", "≥": ">=", "□": "G", "◇": "F", "○": "X",
}


def preempted(text: str, pos: int, after_operand: bool) -> tuple[str, str] | None:
    """``(sequence, hint)`` if another tool's operator that begins like one of ours starts at ``text[pos]``.

    ``<->`` begins like ``<``, ``!=`` like ``!``: the tokenizer asks before it reads them as those. Else None.
    ``after_operand``: the token before is a number, a name or ``)`` (``x <> 1`` is not-equal, ``<>`` alone F).
    """
    for symbol in _PREEMPTED:
        if text.startswith(symbol, pos):
            if after_operand and symbol in _BETWEEN_OPERANDS:
                return symbol, _BETWEEN_OPERANDS[symbol]
            return symbol, dict(SYMBOLS)[symbol]
    return None


def hint_at(text: str, pos: int, before: str | None) -> str | None:
    """The hint for the unknown character at ``text[pos]``; ``before`` is the raw text of the token before it."""
    if text.startswith("[", pos) or text.startswith("{", pos):
        interval = any(c in text[pos : text.find("]", pos) + 1 or len(text)] for c in ",:")  # [0,10], [0:5]
        operator = before is not None and before.rstrip("_") in ("F", "G", "X", "U", "eventually", "always",
                                                                   "until", "next")
        if operator and (interval or text.startswith("{", pos)):
            return _BOUNDED
        if text.startswith("[]", pos):
            return dict(SYMBOLS)["[]"]
        return _NAMES if before is not None and (before.isidentifier() or operator) else None
    if text.startswith("=", pos) and before in ("<", ">"):
        return f"did you mean '{before}='? (no space inside it)"
    return next((hint for symbol, hint in SYMBOLS if text.startswith(symbol, pos)), None)


def hint_for_word(word: str) -> str | None:
    """The hint for an operator or constant of another tool, or for fused operator letters (``GF``)."""
    if word in WORDS:
        return WORDS[word]
    if word.lower() in ("inf", "infinity", "nan"):  # Inf, INF, NaN, NAN: the same words
        return WORDS[word.lower()]
    if len(word) > 1 and set(word) <= set("FGX"):
        return f"operators are separate words: write {' '.join(word)}"
    return None
