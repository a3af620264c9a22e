"""Compiled (numba) iterations of batched least squares matching; optional.

:func:`core.lsm.match` prepares the templates, their normal matrices and the search
windows with numpy, then iterates the inverse compositional Gauss–Newton steps of
one window round.  The numpy path does each step for all patches at once (about
ten array passes per iteration); this module does the same steps in one compiled
loop over the patches (:func:`iterate_round`): sampling, residuals, ``Jᵀe``, the
8 × 8 (or closed-form 4 × 4) solve, the warp composition, the convergence rule and
the rejections, with the same lock-step over the working set as the numpy path (the
first iteration uses the coarse pixel subset exactly when every patch of the set is
still shift-only).  Numerical differences to the numpy path: sums in float64 here
(float32 GEMVs there), i.e. positions equal to ~1e-6 px except for a patch whose
last shift change lies within rounding of ``tol_px``.

Also compiled: the normal matrices and their inverses
(:mod:`core.lsm_kernel_linalg`), the template windows and the 2× upsampled search
windows (:mod:`core.lsm_kernel_sample`).  All loops over patches; single-threaded (``nogil``:
:func:`core.lsm.match`'s ``workers`` threads run them in parallel).

Optional at run time: without numba (Blender does not bundle it), or with the
environment variable ``SOMACAP_NO_NUMBA=1``, :func:`enabled` is False and
:mod:`core.lsm` runs its numpy path, the reference.  Compiled code is cached on disk
(:func:`core.lsm_kernel_jit.jit`).  The first call per argument types compiles (or
loads from the cache) under a lock with numba's warnings silenced; if it fails, the
kernel is off for the process (:func:`failure`) and the call is redone with numpy.
"""

from __future__ import annotations

import threading
import time
import warnings

import numpy as np

from .image_stack import _HALF_TAPS
from .lsm_design import FLAT_SD
from .lsm_kernel_jit import ENV_OFF as ENV_OFF  # re-exported: the switch
from .lsm_kernel_jit import env_off, jit, numba
from .lsm_kernel_linalg import _inv4, _normal_matrices, _solve4, _spd_inverses
from .lsm_kernel_sample import _bilinear, _sample_grid, _template_lines, _upsampled_windows

_LOCK = threading.Lock()
_COMPILED: dict = {}  # argument types -> seconds of the first call
_FAILED = {"error": None}  # why a first call failed (kernel off then)


class KernelError(RuntimeError):
    """A compiled step failed on its first call (compiling); :func:`core.lsm.match`
    then redoes the call on its numpy path, and the kernel stays off in this process."""


def enabled() -> bool:
    """Whether :func:`core.lsm.match` runs the compiled steps (numba imported, no
    compilation failed, ``SOMACAP_NO_NUMBA`` not set to a true value now)."""
    return numba is not None and _FAILED["error"] is None and not env_off()


def failure() -> str | None:
    """The error of a failed first call (the kernel is off since), or None."""
    return _FAILED["error"]


_SUB = (0, 3, 6, 7)


@jit(fastmath={"reassoc"})
def _sums_full(S, T, gx, gy, w, xs, ys, g, o, b):
    """``b = Jᵀ W e`` (8,) and ``vᵀ W v`` (returned) of one patch, residuals
    ``e = g S + o - T`` in float32 (as the numpy path), sums in float64."""
    b0 = b1 = b2 = b3 = b4 = b5 = b6 = b7 = vv = 0.0
    for j in range(T.size):
        ej = (S[j] * g + o) - T[j]
        ew = ej * w[j]
        ugx = gx[j] * ew
        ugy = gy[j] * ew
        b0 += ugx
        b1 += ugx * xs[j]
        b2 += ugx * ys[j]
        b3 += ugy
        b4 += ugy * xs[j]
        b5 += ugy * ys[j]
        b6 += ew
        b7 += T[j] * ew
        vv += ew * ej
    b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7] = b0, b1, b2, b3, b4, b5, b6, b7
    return vv


@jit(fastmath={"reassoc"})
def _sums_coarse(S, T, gx, gy, g, o, b):
    """The shift-and-radiometry part of :func:`_sums_full` on the coarse subset,
    unweighted (b[1, 2, 4, 5] = 0)."""
    b0 = b3 = b6 = b7 = vv = 0.0
    for j in range(T.size):
        ej = (S[j] * g + o) - T[j]
        b0 += gx[j] * ej
        b3 += gy[j] * ej
        b6 += ej
        b7 += ej * T[j]
        vv += ej * ej
    b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7] = b0, 0.0, 0.0, b3, 0.0, 0.0, b6, b7
    return vv


@jit()
def _iterate_round(
    img,
    rpc,
    size,
    bu,
    bv,
    w_lo,
    w_hi,
    f,
    todo,
    T,
    gx,
    gy,
    wpx,
    xs,
    ys,
    T_c,
    gx_c,
    gy_c,
    xs_c,
    ys_c,
    mom_c,
    Ninv,
    N,
    pd,
    uv,
    A,
    gain,
    offset,
    fresh,
    shift_only,
    iters,
    it_left,
    sigma0,
    status,
    uv_s0,
    t_mean,
    t_sd,
    t_sq,
    dof,
    dof_c,
    tol_px,
    max_shift_px,
    half,
    img_hi_u,
    img_hi_v,
    weighted,
    rewindow,
):
    """The iterations of one window round of :func:`core.lsm_solve._match_part` (see there).

    ``todo`` (n_t,) the patches of the round, row k of the window arrays (``bu``,
    ``bv``, ``w_lo``, ``w_hi``) belonging to ``todo[k]``; ``img`` the sampled source
    (a whole mosaic: ``rpc`` = 0, or chunks of ``rpc`` windows of ``size`` rows, ``bv``
    counted from the top of window k's chunk, as :class:`core.image_stack.PatchSource`).
    Updates the per-patch state arrays in place and sets ``rewindow[k]`` for the
    patches that left their window with iterations left.
    """
    n_t = todo.size
    npx = T.shape[1]
    S = np.empty(npx, np.float32)
    b = np.empty(8)
    dq = np.empty(8)
    s4 = np.empty(4)
    blk = np.empty((4, 4))
    Nb = np.empty((4, 4))
    An = np.empty((2, 2))
    active = np.arange(n_t)
    hx = 0.0  # largest |x|, |y| of a template pixel
    for j in range(npx):
        hx = max(hx, abs(np.float64(xs[j])), abs(np.float64(ys[j])))
    # The square grids of template offsets (full, coarse: every other pixel).
    gnf = int(np.sqrt(npx) + 0.5)
    g0f = int(xs[0])
    gnc = int(np.sqrt(xs_c.size) + 0.5)
    g0c = int(xs_c[0])
    n_act = n_t
    while n_act > 0:
        coarse = True
        for q in range(n_act):
            if not shift_only[todo[active[q]]]:
                coarse = False
                break
        n_keep = 0
        for q in range(n_act):
            k = active[q]
            a = todo[k]
            so = shift_only[a]
            base_u = bu[k]
            base_v_loc = bv[k]
            if rpc > 0:
                r0 = (k // rpc) * rpc * size
                rows = min(rpc * size, img.shape[0] - r0)
            else:
                r0 = 0
                rows = img.shape[0]
            # Snapped warp (1/32 px of the source), as the numpy path.
            mu0 = np.rint((base_u + f * uv[a, 0]) * 32.0) / 32.0
            mv0 = np.rint((base_v_loc + f * uv[a, 1]) * 32.0) / 32.0
            mu1 = np.rint(f * A[a, 0, 0] * 32.0) / 32.0
            mu2 = np.rint(f * A[a, 0, 1] * 32.0) / 32.0
            mv1 = np.rint(f * A[a, 1, 0] * 32.0) / 32.0
            mv2 = np.rint(f * A[a, 1, 1] * 32.0) / 32.0
            us = (mu0 - base_u) / f
            vs = (mv0 - base_v_loc) / f
            as00, as01, as10, as11 = mu1 / f, mu2 / f, mv1 / f, mv2 / f
            m_u0, m_u1, m_u2 = np.float32(mu0), np.float32(mu1), np.float32(mu2)
            m_v0, m_v1, m_v2 = np.float32(mv0), np.float32(mv1), np.float32(mv2)
            if coarse:
                xs_s, ys_s = xs_c, ys_c
            else:
                xs_s, ys_s = xs, ys
            npt = xs_s.size
            # All four neighbours of every sample inside the source: no clamping.
            ru = hx * (abs(mu1) + abs(mu2))
            rv = hx * (abs(mv1) + abs(mv2))
            if (
                mu0 - ru >= 0.0
                and mu0 + ru < img.shape[1] - 1.0
                and mv0 - rv >= 0.0
                and mv0 + rv < rows - 1.0
            ):
                _sample_grid(
                    img,
                    r0,
                    int(mu0 * 32.0),
                    int(mv0 * 32.0),
                    int(mu1 * 32.0),
                    int(mu2 * 32.0),
                    int(mv1 * 32.0),
                    int(mv2 * 32.0),
                    g0c if coarse else g0f,
                    2 if coarse else 1,
                    gnc if coarse else gnf,
                    S,
                )
            else:
                for j in range(npt):
                    pu = m_u0 + m_u1 * xs_s[j] + m_u2 * ys_s[j]
                    pv = m_v0 + m_v1 * xs_s[j] + m_v2 * ys_s[j]
                    S[j] = _bilinear(img, r0, rows, pu, pv)
            flat = False
            if fresh[a]:
                s1 = 0.0
                s2 = 0.0
                for j in range(npt):
                    s1 += S[j]
                    s2 += np.float64(S[j]) * S[j]
                sm = s1 / npt
                ssd = np.sqrt(max(s2 / npt - sm * sm, 0.0))
                flat = ssd <= FLAT_SD
                g0 = t_sd[a] / max(ssd, FLAT_SD) if ssd > FLAT_SD else 1.0
                gain[a] = g0
                offset[a] = t_mean[a] - g0 * sm
                fresh[a] = False
            g_old = gain[a]
            o_old = offset[a]
            g32 = np.float32(g_old)
            o32 = np.float32(o_old)
            if coarse:
                vv = _sums_coarse(S, T_c[a], gx_c[a], gy_c[a], g32, o32, b)
                _solve4(mom_c[a], b[0], b[3], b[6], b[7], s4)
                for i in range(8):
                    dq[i] = 0.0
                for i in range(4):
                    dq[_SUB[i]] = s4[i]
                dof_a = dof_c
            else:
                vv = _sums_full(S, T[a], gx[a], gy[a], wpx, xs, ys, g32, o32, b)
                dof_a = dof[a]
                if so:
                    if pd[a]:
                        for i in range(4):
                            for j in range(4):
                                Nb[i, j] = N[a, _SUB[i], _SUB[j]]
                        if not _inv4(Nb, blk):
                            for i in range(4):
                                for j in range(4):
                                    blk[i, j] = np.nan
                    else:
                        for i in range(4):
                            for j in range(4):
                                blk[i, j] = 1.0 if i == j else 0.0
                    for i in range(8):
                        dq[i] = 0.0
                    for i in range(4):
                        acc = 0.0
                        for j in range(4):
                            acc += blk[i, j] * b[_SUB[j]]
                        dq[_SUB[i]] = acc
                else:
                    for i in range(8):
                        acc = 0.0
                        for j in range(8):
                            acc += Ninv[a, i, j] * b[j]
                        dq[i] = acc
            ok_step = True
            for i in range(8):
                if not np.isfinite(dq[i]):
                    ok_step = False
            if not ok_step:
                for i in range(8):
                    dq[i] = 0.0
            # W <- W ∘ ΔW⁻¹ (core.lsm_design.compose_inverse).
            m00, m01, m10, m11 = 1.0 + dq[1], dq[2], dq[4], 1.0 + dq[5]
            dd = m00 * m11 - m01 * m10
            if not abs(dd) > 1e-6:
                dd = 1.0
            i00, i01, i10, i11 = m11 / dd, -m01 / dd, -m10 / dd, m00 / dd
            An[0, 0] = as00 * i00 + as01 * i10
            An[0, 1] = as00 * i01 + as01 * i11
            An[1, 0] = as10 * i00 + as11 * i10
            An[1, 1] = as10 * i01 + as11 * i11
            un = us - (An[0, 0] * dq[0] + An[0, 1] * dq[3])
            vn = vs - (An[1, 0] * dq[0] + An[1, 1] * dq[3])
            cu = un - uv[a, 0]
            cv = vn - uv[a, 1]
            uv[a, 0] = un
            uv[a, 1] = vn
            for i in range(2):
                for j in range(2):
                    A[a, i, j] = An[i, j]
            den = 1.0 + dq[7]
            if not abs(den) > 1e-6:
                den = 1.0
            gain[a] = gain[a] / den
            offset[a] = (offset[a] - dq[6]) / den
            iters[a] += 1
            it_left[a] -= 1
            vtv = vv
            for i in range(8):
                vtv -= dq[i] * b[i]
            sigma0[a] = np.sqrt(max(vtv, 0.0) / dof_a)

            conv = abs(cu) < tol_px and abs(cv) < tol_px and not so
            if so and ((abs(cu) < 1.0 and abs(cv) < 1.0) or iters[a] >= 3):
                shift_only[a] = False
            drift = np.hypot(un - uv_s0[a, 0], vn - uv_s0[a, 1]) > max_shift_px
            eu = half * (abs(An[0, 0]) + abs(An[0, 1]))
            ev = half * (abs(An[1, 0]) + abs(An[1, 1]))
            in_img = (
                un - eu >= 1.0 and vn - ev >= 1.0 and un + eu <= img_hi_u and vn + ev <= img_hi_v
            )
            in_win = (
                un - eu >= w_lo[k, 0]
                and vn - ev >= w_lo[k, 1]
                and un + eu <= w_hi[k, 0]
                and vn + ev <= w_hi[k, 1]
            )
            sc = abs(An[0, 0] * An[1, 1] - An[0, 1] * An[1, 0])
            g = gain[a]
            degen = (not ok_step) or sc < 0.25 or sc > 4.0 or g < 0.1 or g > 10.0 or flat
            st = 1  # Status.NOT_CONVERGED
            if conv:
                st = 0
            if drift:
                st = 4
            if degen:
                st = 6
            if not in_img:
                st = 5
            status[a] = st
            if conv:
                # The symmetric radiometry T ≈ r1 S + r0 (see core.lsm).
                if not weighted:
                    m_et = b[6] / npx + t_mean[a]
                    v_et = (vv + 2.0 * b[7] + t_sq[a]) / npx - m_et * m_et
                    go = g_old if abs(g_old) > 1e-9 else 1e-9
                    s_mean = (m_et - o_old) / go
                    s_sd = np.sqrt(max(v_et, 0.0)) / abs(go)
                else:
                    s1 = 0.0
                    s2 = 0.0
                    for j in range(npx):
                        s1 += S[j]
                        s2 += np.float64(S[j]) * S[j]
                    s_mean = s1 / npx
                    s_sd = np.sqrt(max(s2 / npx - s_mean * s_mean, 0.0))
                g1 = t_sd[a] / max(s_sd, FLAT_SD) if s_sd > FLAT_SD else gain[a]
                offset[a] = t_mean[a] - g1 * s_mean
                gain[a] = g1
            going = st == 1
            left = it_left[a] > 0
            if going and left:
                if in_win:
                    active[n_keep] = k
                    n_keep += 1
                else:
                    rewindow[k] = True
        n_act = n_keep


def upsampled_windows(stack, index, u0, v0, wr):
    """:func:`_upsampled_windows` compiled, as ``PatchSource(upsampler=...)`` calls it."""
    n = len(index)
    out = np.empty((n, 4 * wr + 1, 4 * wr + 1), np.float32)
    _first_call(
        _upsampled_windows,
        "windows",
        np.ascontiguousarray(stack.images),
        np.ascontiguousarray(index, np.int64),
        np.ascontiguousarray(u0, np.int64),
        np.ascontiguousarray(v0, np.int64),
        int(wr),
        _HALF_TAPS,
        out,
    )
    return out


def template_lines(stack, index, u0, v0, half, border):
    """The template windows of :func:`core.lsm_design.template_patches` at integer
    centres, compiled (:func:`_template_lines`): windows of ``s = 2 (half + border) + 1``
    pixels from ``(u0, v0)`` (N,) of images ``index`` (N,) of the stack.  Returns
    T (N, m, m), rows and cols (N m, s) float32 (m = 2 half + 1) as
    :func:`core.lsm_design.slopes_of_lines` takes them."""
    n, m = len(index), 2 * half + 1
    s = m + 2 * border
    T = np.empty((n, m, m), np.float32)
    rows = np.empty((n * m, s), np.float32)
    cols = np.empty((n * m, s), np.float32)
    _first_call(
        _template_lines,
        "template",
        np.ascontiguousarray(stack.images),
        np.ascontiguousarray(index, np.int64),
        np.ascontiguousarray(u0, np.int64),
        np.ascontiguousarray(v0, np.int64),
        int(border),
        T,
        rows,
        cols,
    )
    return T, rows, cols


def _first_call(fn, key, *args):
    """Call a compiled function; its first call with these argument types compiles it
    (or loads it from the disk cache) under a lock, numba's warnings silenced (e.g.
    an unwritable cache), and records the seconds in :func:`compile_seconds`."""
    sig = (
        key,
        *(
            (a.dtype, a.ndim, a.flags.c_contiguous, a.flags.writeable)
            if isinstance(a, np.ndarray)
            else type(a)
            for a in args
        ),
    )
    if sig not in _COMPILED:
        with _LOCK:
            if sig not in _COMPILED:
                t0 = time.perf_counter()
                try:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        fn(*args)
                except Exception as exc:  # e.g. a numba version that cannot type it
                    _FAILED["error"] = f"{key}: {type(exc).__name__}: {exc}"[:1000]
                    raise KernelError(_FAILED["error"]) from exc
                _COMPILED[sig] = time.perf_counter() - t0
                return
    fn(*args)


def normal_matrices(T, gx, gy, w, xs, ys):
    """Compiled :func:`core.lsm_design.normal_matrix`: T, gx, gy (n, P) float32, w, xs,
    ys (P,) float32 -> N (n, 8, 8) float64."""
    N = np.empty((len(T), 8, 8))
    _first_call(_normal_matrices, "normal", T, gx, gy, w, xs, ys, N)
    return N


def spd_inverses(N, use):
    """Compiled :func:`core.batched_linalg.spd_inverse` of N (n, 8, 8) (modified: rows
    not in ``use`` (n,) bool set to I): returns Ninv (n, 8, 8) and pd (n,) bool."""
    Ninv = np.empty_like(N)
    pd = np.empty(len(N), np.bool_)
    _first_call(_spd_inverses, "inverse", N, np.ascontiguousarray(use), Ninv, pd)
    return Ninv, pd


def iterate_round(*args) -> None:
    """Run :func:`_iterate_round` compiled (compiling or loading it on first use)."""
    _first_call(_iterate_round, "iterate", *args)


def compile_seconds() -> float:
    """Wall-clock seconds of the first calls in this process (compile or disk-cache
    load, plus those calls' work)."""
    return float(sum(_COMPILED.values()))
