"""The codes of the compiled smoother's programs, shared by their encoder and the kernel that runs them.

`tl_gym.tltl.fused_smooth` writes a formula's plan as arrays of these codes; `tl_gym.tltl.smooth_kernel`
(numba) reads them. Apart, so that neither module imports the other for them.
"""

# step codes
CONST, PRED, NOT, NARY, IMPLIES, NEXT, SUFFIX, REDUCE, THEN_LINEAR, BINARY_AT_ZERO = range(10)
# expression codes
VAR, NUM, NEG, ADD, SUB, MUL, DIV, SQUARE, POW, ABS, SQRT, EXP, LOG, MIN, MAX = range(15)
