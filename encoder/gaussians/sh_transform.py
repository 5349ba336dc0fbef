"""The SH rest as coefficients of a per-scene transform (informative; format 1.6, spec clauses
7.3.17 and 11.11).

The SH rest of a Gaussian (24 values at SH degree 2, 45 at 3) is strongly correlated across its
colour channels and, in real captures, across its coefficients: tools/results/sh_coding.md measured
that a Karhunen-Loeve transform (KLT) of the whole vector, fitted per scene, codes it in 13-34% fewer
bits at equal distortion than today's per-value coding by the same neighbour prediction. The encoder
here:

- fits the KLT of the SH rest in units of each band's step (u = value / band step): the eigenvectors
  of its covariance, by decreasing variance, so that coefficient k sits in channel 3 + k and the
  per-Gaussian SH degree (clause 11.9) keeps the first 3 (D + 1)^2 - 3 coefficients ("components
  below a count": the ones that carry the most);
- writes it as the integer matrix T = round(A 2^(GUARD_BITS + SHIFT)) with the rounding shift SHIFT,
  so that the decoder's integer inverse gives each SH-rest value in units of 2^-GUARD_BITS of its
  band step, the step the parameter set then carries (band step / 2^GUARD_BITS): the value grid adds
  (2^-GUARD_BITS)^2 / 12 of a step squared of error, 1/256 of a rounding's;
- quantizes (rounds, or RDOQ's choice) in the coefficient domain at one coefficient step (the band
  steps' own precision: an orthonormal transform keeps the error), with each coefficient's sensitivity
  the diagonal of B^T F B (B the matrix from coefficients to values, F the pictures' sensitivity to
  each value): the expected picture error of independent coefficient errors, so that RDOQ, step
  adjustment and the SH-degree choice keep weighing the SH error by what it does to the renders;
- uses the tool only where it pays: the ideal bits of the rounded SH rest (each channel's empirical
  entropy) fall by more than the unit's bits.
"""

from __future__ import annotations

import numpy as np

from ...common.attributes import SH_REST_START, ShTransform

# Fraction bits of the SH-rest values' integers (value grid 2^-GUARD_BITS of the band step) and the
# matrix's rounding shift: T's entries are within 2^(GUARD_BITS + SHIFT) = 2^14 (15 bits, the unit's
# entries offset binary), and its relative precision 2^-14.
GUARD_BITS = 4
SHIFT = 10
ENTRY_LIMIT = 1 << (GUARD_BITS + SHIFT)
# At most this many rows fit the covariance (a sample in normative order beyond it)
FIT_ROWS = 1 << 18


def guard_factor() -> float:
    """The factor between a band step and the step the parameter set carries with the transform."""
    return float(1 << GUARD_BITS)


def fit_klt(u: np.ndarray) -> np.ndarray:
    """float64 [n, n] orthonormal: the eigenvectors (columns) of the covariance of ``u`` [N, n] (the
    SH rest in band steps), by decreasing eigenvalue; each column's sign makes its largest entry
    positive (a deterministic choice)."""
    rows = u[fit_rows(u.shape[0])]
    # the variables as contiguous rows: np.cov of the transposed columns (Fortran order) took a slow
    # product, 1.6-3.2 s at 100k x 45 against 0.16
    c = np.cov(np.ascontiguousarray(rows.T, dtype=np.float64)) if rows.shape[0] > 1 else np.eye(u.shape[1])
    c = np.atleast_2d(c)
    w, v = np.linalg.eigh(c)
    v = v[:, np.argsort(-w, kind="stable")]
    signs = np.sign(v[np.argmax(np.abs(v), axis=0), np.arange(v.shape[1])])
    return v * np.where(signs == 0, 1.0, signs)


def fit_rows(n: int) -> slice | np.ndarray:
    """The rows of n that fit_klt fits the covariance to: all, or FIT_ROWS of them evenly spaced in
    normative order."""
    return slice(None) if n <= FIT_ROWS else np.linspace(0, n - 1, FIT_ROWS).astype(np.int64)


def integer_transform(a: np.ndarray) -> ShTransform:
    """The sh_transform of the orthonormal ``a`` (values in band steps = a @ coefficients):
    T = round(a 2^(GUARD_BITS + SHIFT)) within the entries' range."""
    t = np.clip(np.rint(a * float(ENTRY_LIMIT)), -ENTRY_LIMIT, ENTRY_LIMIT - 1).astype(np.int64)
    return ShTransform(SHIFT, tuple(int(x) for x in t.ravel()))


def value_matrix(transform: ShTransform) -> np.ndarray:
    """float64 [n, n] B: the SH-rest values in band steps are B @ t for coefficients t (the decoder's
    inverse without its rounding)."""
    return transform.array.astype(np.float64) / float(ENTRY_LIMIT)


def forward(u: np.ndarray, transform: ShTransform) -> np.ndarray:
    """float64 [N, n]: the coefficients whose inverse is closest to ``u`` [N, n] (band steps): B^-1 u,
    solved by blocks of rows (solve_blocks: the bits of one solve of every row, without its [N, n]
    working copies)."""
    b = value_matrix(transform)
    out = np.empty(u.shape, dtype=np.float64)
    for rows in solve_blocks(u.shape[0]):
        out[rows] = np.linalg.solve(b, np.asarray(u[rows], np.float64).T).T
    return out


# The rows of one solve in forward: 23-47 MB of float64 at SH 3
FORWARD_BLOCK_ROWS = 1 << 16


def solve_blocks(n: int):
    """Slices of rows 0 .. n - 1 for forward's solves: one under 2 x FORWARD_BLOCK_ROWS rows, else blocks
    of FORWARD_BLOCK_ROWS with the last one's rest added to it. LAPACK solves each row (right-hand side)
    by itself, with the same operations wherever it sits in a wide block, but a narrow one (a handful of
    rows) may take the library's small-size paths, whose last bits differ: so no block is narrower than
    FORWARD_BLOCK_ROWS (a multiple of the kernels' widths), and a block's last rows are the whole solve's
    last rows (checked bit for bit on 200k and 1M rows: tests/test_sh_transform.py)."""
    lo = 0
    while lo < n:
        hi = n if n - lo < 2 * FORWARD_BLOCK_ROWS else lo + FORWARD_BLOCK_ROWS
        yield slice(lo, hi)
        lo = hi
def coefficient_sensitivity(f_rest: np.ndarray, band_steps: np.ndarray, transform: ShTransform) -> np.ndarray:
    """float64 [N, n]: each coefficient's sensitivity, diag(B^T F B) per Gaussian with F the pictures'
    sensitivity to the values ``f_rest`` [N, n] (per value) and B in values: band_steps[j] * B[j, k]."""
    b = value_matrix(transform) * np.asarray(band_steps, np.float64)[:, None]
    return np.asarray(f_rest, np.float64) @ (b * b)


def _column_bits(col: np.ndarray) -> float:
    """Ideal bits of the integers ``col`` [N] coded with their histogram, negated."""
    _, counts = np.unique(col, return_counts=True)
    p = counts / counts.sum()
    return float((counts * np.log2(p)).sum())


def _entropy_bits(q: np.ndarray) -> float:
    """Ideal bits of the integers ``q`` [N, n] coded column by column with each column's histogram."""
    total = 0.0
    for col in q.T:
        total -= _column_bits(col)
    return total


def transform_pays(u: np.ndarray, transform: ShTransform, sh_degree: int) -> bool:
    """Whether the rounded coefficients of ``u`` (band steps) take fewer ideal bits than the rounded
    values by more than the unit's own bits (a scene that the transform does not help pays nothing)."""
    if u.shape[1] == 0 or u.shape[0] < 2:
        return False
    unit_bits = 8 * len(transform.to_unit(sh_degree).to_bytes())
    return _entropy_bits(np.rint(u)) - _entropy_bits(np.rint(forward(u, transform))) > unit_bits


def chosen_transform(u: np.ndarray, mode: bool | str, sh_degree: int) -> ShTransform | None:
    """The scene's transform of the SH rest ``u`` [N, n] (band steps) as ``mode`` (the configuration's
    ``sh_transform``: False, True where it pays, or "always") asks; None without one."""
    if not mode or sh_degree == 0 or u.shape[1] == 0:
        return None
    transform = integer_transform(fit_klt(u))
    if mode != "always" and not transform_pays(u, transform, sh_degree):
        return None
    return transform


def chosen_transform_of_values(values: np.ndarray, rest: slice, band_steps: np.ndarray, mode: bool | str,
                               sh_degree: int) -> tuple[ShTransform | None, np.ndarray | None]:
    """chosen_transform of the SH rest in band steps, u = values[:, rest] / band_steps (``values``
    [N, M] float64, ``band_steps`` float64 [n]), and the coefficients forward(u) (None, None without
    a transform), without u made whole: the fit's rows, a block's or a column's at a time (the same
    numbers, so the same choice and coefficients as from u)."""
    n, columns = values.shape[0], range(values.shape[1])[rest]
    if not mode or sh_degree == 0 or len(columns) == 0:
        return None, None
    transform = integer_transform(fit_klt(values[fit_rows(n), rest] / band_steps))
    coefficients = np.empty((n, len(columns)), dtype=np.float64)
    for block in solve_blocks(n):
        coefficients[block] = forward(values[block, rest] / band_steps, transform)
    if mode != "always":  # transform_pays, the rounded values a column at a time
        if n < 2:
            return None, None
        bits_u = bits_t = 0.0
        for j, c in enumerate(columns):
            bits_u -= _column_bits(np.rint(values[:, c] / band_steps[j]))
        for j in range(len(columns)):
            bits_t -= _column_bits(np.rint(coefficients[:, j]))
        if not bits_u - bits_t > 8 * len(transform.to_unit(sh_degree).to_bytes()):
            return None, None
    return transform, coefficients


def sh_rest_columns(sh_channels: int) -> slice:
    return slice(SH_REST_START, sh_channels)
