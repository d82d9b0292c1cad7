"""Subspace identification: closed-loop-safe PBSID start and open-loop PO-MOESP.

``pbsid`` (predictor-based subspace identification, Chiuso 2007 "The role of VARX
modeling in PBSID"; the idea behind MATLAB's SSARX weighting) first fits a
high-order VARX *predictor* y[k] = sum_j (Xi_j^y y[k-j] + Xi_j^u u[k-j]) + e[k] by
least squares.  The predictor needs no open-loop assumption, so feedback does not
bias it (direct approach).  Its Markov parameters C F^(j-1) [K, B] (F = A - K C)
give Gamma_f x[k] = sum_j Theta z[k-j]; an SVD yields the state sequence and least
squares A, B, C, K.  ``po_moesp`` is the classical open-loop past-output MOESP, which
is biased under feedback (reference F3, T7); it is here to show exactly that.

Memory: the VARX regression at N samples and order p costs N x p (l + m) doubles;
the data are decimated first (``decimate``), outputs subsampled and the input
block-averaged (the exact ZOH input of the coarse sampling would be the average),
so that N = 50,000 samples at 100 Hz need ~15 MB.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import cho_factor, cho_solve, logm

from bikeid.sim.errors import UntrustworthyResult

__all__ = ["d2c", "pbsid", "po_moesp", "decimate"]


def decimate(u: np.ndarray, y: np.ndarray, factor: int) -> tuple[np.ndarray, np.ndarray]:
    """Decimate input-output data: outputs subsampled, inputs block-averaged.

    Averaging the input over each block is ZOH-consistent: it is the exact held input
    of the coarse sampling when the fine input is itself held.

    Parameters
    ----------
    u : (N,) or (N, m) array_like
        Inputs (any units; e.g. T_delta [N m]).
    y : (N,) or (N, l) array_like
        Outputs, same number of samples as ``u`` (not checked).
    factor : int
        Decimation factor; <= 1 returns the data unchanged (reshaped to 2-D).

    Returns
    -------
    u_d : (N // factor, m) ndarray
        Block means of ``u`` (a last incomplete block is dropped).
    y_d : (N // factor, l) ndarray
        ``y[:n:factor]`` with n = (N // factor) * factor: the sample at the start of
        each block.  The new sample period is ``factor`` times the old one.
    """
    u = np.asarray(u, float).reshape(len(u), -1)
    y = np.asarray(y, float).reshape(len(y), -1)
    if factor <= 1:
        return u, y
    n = (len(u) // factor) * factor
    return u[:n].reshape(-1, factor, u.shape[1]).mean(axis=1), y[:n:factor]


def _past(data: np.ndarray, p: int) -> np.ndarray:
    """Rows k = p..N-1 holding [d[k-1], d[k-2], ..., d[k-p]]."""
    N = data.shape[0]
    return np.hstack([data[p - j : N - j] for j in range(1, p + 1)])


def _regression(Z: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Least-squares X of Z X = Y for a tall Z of full column rank.

    Cholesky of Z'Z with one step of iterative refinement (the residual's normal equations
    solved again), several times faster than the SVD of ``numpy.linalg.lstsq`` for the
    VARX regression; the SVD where Z'Z is not numerically positive definite.
    """
    G = Z.T @ Z
    try:
        c = cho_factor(G, check_finite=False)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(Z, Y, rcond=None)[0]
    X = cho_solve(c, Z.T @ Y, check_finite=False)
    X += cho_solve(c, Z.T @ (Y - Z @ X), check_finite=False)
    if not np.all(np.isfinite(X)):
        return np.linalg.lstsq(Z, Y, rcond=None)[0]
    return X


def pbsid(
    u: np.ndarray | list, y: np.ndarray | list, n: int = 4, p: int = 40
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closed-loop-safe subspace estimate (A, B, C, K) of the innovations model.

    x[k+1] = A x[k] + B u[k] + K e[k], y[k] = C x[k] + e[k] (no feedthrough),
    discrete time with the data's sample period, in an arbitrary state basis.

    Parameters
    ----------
    u : (N, m) array_like or list of them
        Inputs; a 1-D array is one input.  A *list* means several runs (each an
        array), stacked after forming the regressors; a single run must therefore
        be an array, not a list of numbers.
    y : (N, l) array_like or list of them
        Outputs, matching ``u`` run by run.
    n : int, optional
        Model order (state dimension). Default 4.
    p : int, optional
        Past window (VARX order); it must cover the decay of the predictor,
        p dt >~ 2 / |slowest predictor pole|.  Every run needs more than 3 p samples.
        Default 40.

    Returns
    -------
    A : (n, n) ndarray
        Discrete state matrix.
    B : (n, m) ndarray
        Discrete input matrix.
    C : (l, n) ndarray
        Output matrix.
    K : (n, l) ndarray
        Innovations (Kalman) gain.

    Raises
    ------
    ValueError
        If a run has 3 p samples or fewer, or ``u`` and ``y`` hold different numbers
        of runs.
    """
    us = u if isinstance(u, list) else [u]
    ys = y if isinstance(y, list) else [y]
    Zs, Ys = [], []
    for ui, yi in zip(us, ys, strict=True):
        ui = np.asarray(ui, float).reshape(len(ui), -1)
        yi = np.asarray(yi, float).reshape(len(yi), -1)
        if len(yi) <= 3 * p:
            raise ValueError(f"a run of {len(yi)} samples is too short for past window p={p}")
        Zs.append(_past(np.hstack([yi, ui]), p))
        Ys.append(yi[p:])
    Z, Yf = np.vstack(Zs), np.vstack(Ys)
    l, m = Yf.shape[1], us[0].reshape(len(us[0]), -1).shape[1]
    q = l + m
    Xi = _regression(Z, Yf)  # (p q, l)
    Xi = Xi.T  # (l, p q): blocks Xi_j = C F^(j-1) [K, B]
    f = p
    Theta = np.zeros((f * l, p * q))
    for i in range(f):  # block row i: Xi_(i + j) in block column j
        Theta[i * l : (i + 1) * l, : (p - i) * q] = Xi[:, i * q : p * q]
    # SVD of Theta Z' through its Gram matrix (f l x f l)
    TZ = Z @ Theta.T  # (N, f l)
    w, V = np.linalg.eigh(TZ.T @ TZ)
    Un = V[:, np.argsort(w)[::-1][:n]]
    X = TZ @ Un  # (N, n) state sequence
    # y = C x + e
    Cm, *_ = np.linalg.lstsq(X, Yf, rcond=None)
    E = Yf - X @ Cm
    C = Cm.T
    # per run: x[k+1] = A x[k] + B u[k] + K e[k]
    rows_x, rows_r = [], []
    start = 0
    for ui, yi in zip(us, ys, strict=True):
        ni = len(yi) - p
        Xi_ = X[start : start + ni]
        Ui = np.asarray(ui, float).reshape(len(ui), -1)[p:]
        Ei = E[start : start + ni]
        rows_r.append(np.hstack([Xi_[:-1], Ui[:-1], Ei[:-1]]))
        rows_x.append(Xi_[1:])
        start += ni
    R, Xn = np.vstack(rows_r), np.vstack(rows_x)
    ABK, *_ = np.linalg.lstsq(R, Xn, rcond=None)
    ABK = ABK.T
    return ABK[:, :n], ABK[:, n : n + m], C, ABK[:, n + m :]


def po_moesp(
    u: np.ndarray, y: np.ndarray, n: int = 4, f: int = 20
) -> tuple[np.ndarray, np.ndarray]:
    """Open-loop PO-MOESP estimate of (A, C) (Verhaegen 1994).

    Past inputs and outputs are the instruments.  Consistent in open loop, biased
    under feedback (reference F3).

    Parameters
    ----------
    u : (N,) or (N, m) array_like
        Inputs.
    y : (N,) or (N, l) array_like
        Outputs, same N.
    n : int, optional
        Model order. Default 4.
    f : int, optional
        Block (future and past horizon) size; needs N - 2 f + 1 >= 10 f. Default 20.

    Returns
    -------
    A : (n, n) ndarray
        Discrete state matrix, in the basis of the extended observability matrix.
    C : (l, n) ndarray
        Output matrix in the same basis.

    Raises
    ------
    ValueError
        If there are too few samples for the block size ``f``.
    """
    u = np.asarray(u, float).reshape(len(u), -1)
    y = np.asarray(y, float).reshape(len(y), -1)
    m, l = u.shape[1], y.shape[1]
    N = len(y) - 2 * f + 1
    if N < 10 * f:
        raise ValueError(f"too few samples ({len(y)}) for block size f={f}")

    def hank(d, start):
        return np.vstack([d[start + i : start + i + N].T for i in range(f)])

    Up, Uf, Yp, Yf = hank(u, 0), hank(u, f), hank(y, 0), hank(y, f)
    H = np.vstack([Uf, Up, Yp, Yf])
    L = np.linalg.qr(H.T, mode="r").T
    r1, r2 = f * m, f * (m + l)
    L32 = L[r1 + r2 :, r1 : r1 + r2]
    U, _, _ = np.linalg.svd(L32, full_matrices=False)
    G = U[:, :n]
    A, *_ = np.linalg.lstsq(G[:-l], G[l:], rcond=None)
    return A, G[:l]


def _principal_log(Z: np.ndarray) -> np.ndarray:
    """Principal matrix logarithm: V diag(log w) V^-1 from the eigendecomposition where the
    eigenvectors are well conditioned (condition below 1e4: rounding ~1e-12, a few hundred
    times faster than ``scipy.linalg.logm`` at this size), else ``logm``."""
    w, V = np.linalg.eig(Z)
    if np.all(w != 0) and np.linalg.cond(V) < 1e4:
        return (V * np.log(w.astype(complex))) @ np.linalg.inv(V)
    return logm(Z)


def d2c(
    A: np.ndarray, B: np.ndarray, dt: float, strict: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of the zero-order-hold discretization (principal matrix logarithm).

    [[A_c, B_c], [0, 0]] = logm([[A, B], [0, I]]) / dt, the inverse of
    :func:`sim.sampling.zoh`.  A discrete pole on the negative real axis has no real
    logarithm: ``strict`` raises ValueError, otherwise the real part is returned
    (good enough as a start).

    Parameters
    ----------
    A : (n, n) ndarray
        Discrete state matrix.
    B : (n, m) ndarray
        Discrete input matrix.
    dt : float
        Sample period [s].
    strict : bool, optional
        Refuse models without a real continuous-time equivalent. Default True.

    Returns
    -------
    Ac : (n, n) ndarray
        Continuous state matrix (per second).
    Bc : (n, m) ndarray
        Continuous input matrix.

    Raises
    ------
    ValueError
        If ``strict`` and the matrix logarithm is not real.
    """
    n, m = B.shape
    Z = np.zeros((n + m, n + m))
    Z[:n, :n], Z[:n, n:], Z[n:, n:] = A, B, np.eye(m)
    L = _principal_log(Z) / dt
    L = np.real_if_close(L, tol=1e6)
    if np.iscomplexobj(L):
        if not strict:
            L = L.real
            return L[:n, :n], L[:n, n:]
        raise UntrustworthyResult("the discrete model has no real continuous-time ZOH equivalent")
    return L[:n, :n], L[:n, n:]
