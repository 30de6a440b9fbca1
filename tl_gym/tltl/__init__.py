"""The TLTL engine: syntax tree, parser and evaluators. It knows nothing of Gymnasium."""

from tl_gym.tltl.ast import Formula
from tl_gym.tltl.parser import parse

__all__ = ["Formula", "parse"]
