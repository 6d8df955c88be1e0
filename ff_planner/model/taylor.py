"""Arithmetic on truncated Taylor rows in the friction parameters and the step currents.

A row holds x = x0 + Σ_i x_pi·εp_i + Σ_j x_Ij·εI_j + Σ_ij x_piIj·εp_i·εI_j for the NP = 3
friction parameters p = (pv, pc, pt) and N step currents I_j (A): its value, ∂x/∂p (3), ∂x/∂I (N)
and the mixed ∂²x/∂p∂I (3×N). Layout (length 4 + 4N): [value, d/dpv, d/dpc, d/dpt, d/dI_0..,
d²/dpv dI_0.., d²/dpc dI_0.., d²/dpt dI_0..]. Rows live in a preallocated 2-D workspace W and are
named by their row index; every operation writes row ``o`` in place (no allocation), and ``o``
may alias an operand.
"""
from __future__ import annotations

from numba import njit

NP = 3   # friction parameters pv, pc, pt


def row_len(n: int) -> int:
    """Length of one Taylor row for N step currents."""
    return 4 + 4 * n


@njit("void(float64[:, ::1], int64, float64)", cache=True, nogil=True)
def row_const(W, o, val):
    """o = val (a constant: all derivatives zero)."""
    for k in range(W.shape[1]):
        W[o, k] = 0.0
    W[o, 0] = val


@njit("void(float64[:, ::1], int64, int64)", cache=True, nogil=True)
def row_copy(W, o, x):
    """o = x."""
    for k in range(W.shape[1]):
        W[o, k] = W[x, k]


@njit("void(float64[:, ::1], int64, int64, int64, float64, float64, float64)",
      cache=True, nogil=True)
def row_lin(W, o, x, y, al, be, ga):
    """o = al·x + be·y + ga."""
    for k in range(W.shape[1]):
        W[o, k] = al * W[x, k] + be * W[y, k]
    W[o, 0] += ga


@njit("void(float64[:, ::1], int64, int64, int64, int64)", cache=True, nogil=True)
def row_mul(W, o, x, y, n):
    """o = x·y (truncated: no second derivatives in p·p or I·I)."""
    x0 = W[x, 0]
    y0 = W[y, 0]
    base = 4 + n
    for i in range(NP):
        xa = W[x, 1 + i]
        ya = W[y, 1 + i]
        for j in range(n):
            k = base + i * n + j
            W[o, k] = x0 * W[y, k] + y0 * W[x, k] + xa * W[y, 4 + j] + W[x, 4 + j] * ya
    for k in range(1, 4 + n):
        W[o, k] = x0 * W[y, k] + y0 * W[x, k]
    W[o, 0] = x0 * y0


@njit("void(float64[:, ::1], int64, int64, float64, float64, float64, int64)",
      cache=True, nogil=True)
def row_uni(W, o, x, g0, g1, g2, n):
    """o = g(x) given g, g', g'' at x's value."""
    base = 4 + n
    for i in range(NP):
        xa = W[x, 1 + i]
        for j in range(n):
            k = base + i * n + j
            W[o, k] = g1 * W[x, k] + g2 * xa * W[x, 4 + j]
    for k in range(1, 4 + n):
        W[o, k] = g1 * W[x, k]
    W[o, 0] = g0
