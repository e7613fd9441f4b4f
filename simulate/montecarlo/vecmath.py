"""An exponential that LLVM can vectorise: the wavelength loops of the spectral scoring.

Why: a loop over wavelengths that calls ``math.exp`` cannot be vectorised without a vector
math library (numba lowers ``math.exp`` to ``llvm.exp``, which becomes one libm call per
element unless Intel SVML is installed; it is not here and is not a dependency). The next-event
estimator evaluates ``exp(-mu_t,l path)`` for every output x wavelength at every vertex -- most of
the summation route's time -- so :func:`vexp` computes it with plain arithmetic
only (no calls, no branches): LLVM turns the loop into SIMD code. The kernel's per-collision
re-weighting ``A_l *= (mu_s^l / mu_s^w) exp(-(mu_t^l - mu_t^w) l)`` uses it too.

Method (Cody & Waite range reduction, as in Cephes ``exp`` and SLEEF)::

    n = round(x / ln 2),   r = x - n ln2_hi - n ln2_lo       |r| <= ln(2) / 2
    exp(x) = 2^n exp(r),   exp(r) by its Taylor polynomial of degree 13 (Horner)

``ln2_hi`` has its low 32 bits zero, so ``n ln2_hi`` is exact for ``|n| < 2^21``; the Taylor
remainder is below ``0.347^14 / 14! < 5e-18`` (relative), under half an ulp, so the result is
within about 2 ulp of the correctly rounded value (measured against ``math.exp`` over
[-708, 0] in ``tests/simulate/mc/test_vecmath.py``). ``2^n`` is built from its IEEE bits
(exponent field ``n + 1023``) by a bit cast. Arguments below ``-708`` (results below the
smallest normal number) give 0, arguments above ``709`` give ``inf`` (``exp(709) = 8.2e307``; the
overflow threshold is 709.78); NaN gives NaN.

References
----------
Cody, W. J. & Waite, W. (1980). *Software Manual for the Elementary Functions*. Prentice-Hall.
Moshier, S. L. (1989). *Methods and Programs for Mathematical Functions* (Cephes). Ellis Horwood.
Shibata, N. & Petrogalli, F. (2020). SLEEF: a portable vectorized library of C standard
mathematical functions. *IEEE Trans. Parallel Distrib. Syst.* 31, 1316-1327.
"""

from __future__ import annotations

import math

import numba
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

__all__ = ["vexp", "EXP_MIN_ARG", "EXP_MAX_ARG"]

#: below this argument :func:`vexp` returns 0 (exp(-708) = 3.3e-308, just above the smallest normal)
EXP_MIN_ARG = -708.0
#: above this argument :func:`vexp` returns inf
EXP_MAX_ARG = 709.0
_LOG2E = 1.4426950408889634
_LN2_HI = 0.693145751953125  # ln 2 rounded to 22 significant bits: n * _LN2_HI is exact
_LN2_LO = 1.4286068203094173e-06  # ln 2 - _LN2_HI


@intrinsic
def _double_from_bits(typingctx, bits):
    """The float64 whose IEEE 754 bit pattern is the int64 ``bits`` (an LLVM bitcast)."""
    sig = types.float64(types.int64)

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())

    return sig, codegen


# fastmath set explicitly to 'contract' only (fused multiply-adds: the reduction and the Horner
# steps only gain from them): without its own setting numba compiles it with the flags of its first
# caller, and the kernel's 'reassoc' folds the two-constant reduction into x - n ln2 (up to ~200 ulp
# near |x| = 700)
@numba.njit(cache=True, error_model="numpy", fastmath={"contract"})
def vexp(x: float) -> float:
    """``exp(x)`` within about 2 ulp, branch-free (module docstring); 0 below ``-708``, inf above ``709``."""
    xc = min(max(x, EXP_MIN_ARG), EXP_MAX_ARG)
    n = math.floor(xc * _LOG2E + 0.5)
    r = (xc - n * _LN2_HI) - n * _LN2_LO
    p = 1.0 / 6227020800.0
    p = p * r + 1.0 / 479001600.0
    p = p * r + 1.0 / 39916800.0
    p = p * r + 1.0 / 3628800.0
    p = p * r + 1.0 / 362880.0
    p = p * r + 1.0 / 40320.0
    p = p * r + 1.0 / 5040.0
    p = p * r + 1.0 / 720.0
    p = p * r + 1.0 / 120.0
    p = p * r + 1.0 / 24.0
    p = p * r + 1.0 / 6.0
    p = p * r + 0.5
    p = p * r + 1.0
    p = p * r + 1.0
    scale = _double_from_bits((int(n) + 1023) << 52)
    y = p * scale
    y = y if x >= EXP_MIN_ARG else 0.0
    y = y if x <= EXP_MAX_ARG else math.inf
    return y if x == x else x
