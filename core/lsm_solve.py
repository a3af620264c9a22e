"""The Gauss–Newton iterations of batched least squares matching over one part of the patches.

:func:`_match_part` is the work of :func:`core.lsm.match` once its inputs are
validated (and, with ``workers``, split into parts): per patch the template, its
cubic-spline gradients and texture, the normal matrix ``N`` of the inverse
compositional step inverted once, the coarse shift-and-radiometry first step, then
rounds of search windows (the patch footprint and :data:`_DRIFT_PX` of drift, upsampled
2×) in which the patches iterate until they converge, fail or leave their window; last
the covariance of the matched points, ``κ σ0² N⁻¹`` mapped by the affine part.  The
method, its statuses and the constraint line are described in :mod:`core.lsm`.  Where
numba runs, each window round is :func:`core.lsm_kernel.iterate_round` (same rules).

Arrays: ``uv_t``, ``uv_s0`` (n, 2) template centres and start positions, pixels;
``ti``, ``si`` (n,) image indices in the stacks; ``A`` (n, 2, 2) the affine part;
grey levels as in the images.
"""

from __future__ import annotations

import numpy as np

from . import lsm_kernel
from .batched_linalg import line_update, spd_inverse
from .image_stack import ImageStack, PatchSource, resampling_noise_factor
from .lsm_design import (
    FLAT_SD,
    _grid,
    coarse_shift_step,
    compose_inverse,
    inverse_blocks,
    normal_matrix,
    row_mean_sd,
    shift_moments,
    template_patches,
)
from .lsm_result import LSMResult, Status

#: Drift allowed for in a search window beyond the patch footprint, px (then a new window).
_DRIFT_PX = 1.0


def _match_part(
    tstack: ImageStack,
    sstack: ImageStack,
    uv_t,
    uv_s0,
    ti,
    si,
    A,
    lines,
    *,
    half,
    upsample,
    tol_px,
    max_iter,
    max_shift_px,
    max_sigma_px,
    min_texture,
    sigma_line_px,
    sigma_grey,
    weight_sigma,
) -> LSMResult:
    """:func:`core.lsm.match` of validated arrays (uv_t, uv_s0 (n, 2), ti, si (n,), A (n, 2, 2)
    owned here, lines None or (normal (n, 2), d (n,)))."""
    n = len(uv_t)
    status = np.full(n, Status.NOT_CONVERGED, dtype=np.int8)
    iters = np.zeros(n, np.int32)
    gain = np.ones(n)
    offset = np.zeros(n)
    sigma0 = np.full(n, np.nan)
    cov = np.full((n, 2, 2), np.nan)

    finite = (
        np.all(np.isfinite(uv_t), axis=1)
        & np.all(np.isfinite(uv_s0), axis=1)
        & np.all(np.isfinite(A), axis=(1, 2))
    )
    status[~finite] = Status.INVALID
    uv_t = np.where(finite[:, None], uv_t, 0.0)
    uv = np.where(finite[:, None], uv_s0, 0.0)
    A[~finite] = np.eye(2)
    t_in = tstack.inside(uv_t[:, 0], uv_t[:, 1], half + 1)
    status[finite & ~t_in] = Status.OUT_OF_IMAGE

    # Template, its gradients and texture (smaller eigenvalue of the structure tensor).
    kernel = lines is None and lsm_kernel.enabled()  # compiled steps (core.lsm_kernel)
    T, tx, ty = template_patches(
        tstack, np.where(t_in[:, None], uv_t, half + 1.0), half, ti, upsample, kernel
    )
    npx = T[0].size
    T = T.reshape(n, npx)
    gx = tx.reshape(n, npx)
    gy = ty.reshape(n, npx)
    t_mean, t_sd = row_mean_sd(T)
    t_sq = npx * (t_sd**2 + t_mean**2)  # Σ T²
    # Normal matrix of the inverse compositional step, inverted once per patch.
    xg, yg = _grid(half)
    xs = xg.ravel().astype(np.float32)
    ys = yg.ravel().astype(np.float32)
    basis = np.stack([np.ones_like(xs), xs, ys])  # (3, P)
    if weight_sigma is None:
        wpx = np.ones(npx, np.float32)
        Tw = T
    else:
        wpx = np.exp(-(xs * xs + ys * ys) / (2.0 * weight_sigma**2)).astype(np.float32)
        Tw = T * wpx
    # b = Jᵀ W e: (w gx e, w gy e, w e) against 1, x, y (three GEMVs, faster than a GEMM).
    basis_w = basis * wpx  # (3, P)
    if kernel:
        T, gx, gy = (np.ascontiguousarray(x) for x in (T, gx, gy))
        N = lsm_kernel.normal_matrices(T, gx, gy, wpx, xs, ys)
    else:
        N = normal_matrix(T, gx, gy, xs, ys, wpx)
    if weight_sigma is None:
        N2 = N
    elif kernel:
        N2 = lsm_kernel.normal_matrices(T, gx, gy, wpx * wpx, xs, ys)
    else:
        N2 = normal_matrix(T, gx, gy, xs, ys, wpx * wpx)
    sw = float(wpx.sum())
    # Texture: smaller eigenvalue of the (weighted) structure tensor, mean of ∇T ∇Tᵀ.
    sxx, syy, sxy = N[:, 0, 0] / sw, N[:, 3, 3] / sw, N[:, 0, 3] / sw
    lam_min = 0.5 * (sxx + syy) - np.sqrt(0.25 * (sxx - syy) ** 2 + sxy**2)
    texture = np.sqrt(np.maximum(lam_min, 0.0))
    status[finite & t_in & (texture < min_texture)] = Status.WEAK_TEXTURE
    if kernel:
        Ninv, pd = lsm_kernel.spd_inverses(N, status == Status.NOT_CONVERGED)
    else:
        N[status != Status.NOT_CONVERGED] = np.eye(8)
        Ninv, pd = spd_inverse(N)
    # Shifts and radiometry only in the first iteration (and until the shift settles
    # below 1 px, at most 3): the affine part of a far-off start would diverge.  The
    # first iteration of all patches (without a line constraint) uses every other
    # pixel in u and v, unweighted (a quarter of the samples; its step only brings the
    # patch near the match) and solves its 4 × 4 system in closed form.
    sub = [0, 3, 6, 7]
    shift_only = np.ones(n, bool)
    side = 2 * half + 1
    even = slice(half % 2, side, 2)  # even offsets x, y

    def coarse(X):
        return np.ascontiguousarray(X.reshape(-1, side, side)[:, even, even]).reshape(len(X), -1)

    basis_c = coarse(basis)
    w_c = np.ones(basis_c.shape[1], np.float32)
    T_c, gx_c, gy_c = coarse(T), coarse(gx), coarse(gy)
    mom_c = shift_moments(T_c, gx_c, gy_c, w_c)
    dof_c = len(w_c) - 4.0
    # Redundancy: tr W - tr(N⁻¹ JᵀW²J) (= n - u for uniform weights).
    if weight_sigma is None:
        dof = np.full(n, npx - 8.0)
    else:
        dof = float(np.sum(wpx)) - np.einsum("nij,nji->n", Ninv, N2)
    dof = dof + (lines is not None)
    status[(status == Status.NOT_CONVERGED) & ~pd] = Status.DEGENERATE

    if lines is not None:
        ln_n, ln_d = lines
        w_line = (sigma_grey / sigma_line_px) ** 2
    _, h_img, w_img = sstack.shape
    img_lo = np.array([1.0, 1.0])
    img_hi = np.array([w_img - 2.0, h_img - 2.0])
    fresh = np.ones(n, bool)  # radiometry not yet initialised
    it_left = np.full(n, max_iter, np.int64)
    uv_s0 = np.ascontiguousarray(uv_s0)

    todo = np.flatnonzero(status == Status.NOT_CONVERGED)
    while todo.size:
        # Search windows around the current positions: the patch footprint and
        # ``_DRIFT_PX`` of drift; patches that walk out of their window (within
        # max_shift_px) get a new one in the next round.
        reach = half * np.max(np.abs(A[todo]).sum(axis=2), axis=1) + _DRIFT_PX
        src = PatchSource(
            sstack,
            si[todo],
            uv[todo],
            reach,
            upsample,
            lsm_kernel.upsampled_windows if kernel else None,
        )
        f = src.f
        bases, w_lo, w_hi = np.stack([src.bu, src.bv]), src.lo, src.hi
        if kernel:
            rew = np.zeros(len(todo), bool)
            lsm_kernel.iterate_round(
                src.up,
                src.rows_per_chunk if not src._whole else 0,
                getattr(src, "size", 0),
                src.bu,
                src.bv,
                src.lo,
                src.hi,
                float(f),
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
                basis_c[1],
                basis_c[2],
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
                float(dof_c),
                float(tol_px),
                float(max_shift_px),
                float(half),
                float(img_hi[0]),
                float(img_hi[1]),
                weight_sigma is not None,
                rew,
            )
            todo = todo[rew]
            continue
        # Working set: the patches still iterating in this window round, with their
        # template arrays (compacted as patches finish).
        a, wrow = todo, np.arange(len(todo))
        if len(todo) == n:
            Ta, Twa, gxa, gya = T, Tw, gx, gy
        else:
            Ta, Twa, gxa, gya = T[todo], Tw[todo], gx[todo], gy[todo]
        rewindow = []
        while a.size:
            na = len(a)
            Aa = A[a]
            # Sampling positions in the source: one GEMM for u and v.
            # cv2.remap samples at positions rounded to 1/32 px of its source: the warp
            # is snapped to that grid (offset and slopes multiples of 1/32, so that
            # every sample position is exact in float32 and for cv2), and the update
            # below starts from the snapped warp actually sampled.
            so = shift_only[a]
            coarse = lines is None and so.all()
            base = bases[:, wrow]  # (2, n_a)
            M = np.empty((2, na, 3))  # [u; v] x (1, x, y)
            M[:, :, 0] = base + f * uv[a].T
            M[:, :, 1:] = f * Aa.transpose(1, 0, 2)
            M = np.rint(M * 32.0) * (1 / 32.0)
            uv_s = ((M[:, :, 0] - base) / f).T
            A_s = M[:, :, 1:].transpose(1, 0, 2) / f
            puv = M.reshape(2 * na, 3).astype(np.float32) @ (basis_c if coarse else basis)
            S = src.sample(puv[:na], puv[na:], wrow)  # (n_a, P or P/4)
            new = fresh[a]
            flat = np.zeros(na, bool)
            if new.any():
                # Radiometric start: match the mean and spread of the grey levels; a
                # flat search patch (no spread: the gain is undetermined) is rejected.
                k = a[new]
                s_mean, s_sd = row_mean_sd(S[new] if not new.all() else S)
                flat[new] = s_sd <= FLAT_SD
                g0 = np.where(s_sd > FLAT_SD, t_sd[k] / np.maximum(s_sd, FLAT_SD), 1.0)
                gain[k] = g0
                offset[k] = t_mean[k] - g0 * s_mean
                fresh[k] = False
            g_old, o_old = gain[a], offset[a]
            if coarse:
                rows = slice(None) if na == n else a
                dq, b, vv = coarse_shift_step(
                    S, g_old, o_old, T_c[rows], gx_c[rows], gy_c[rows], w_c, mom_c[rows]
                )
                dof_a = dof_c
            else:
                # Residuals e = r1 S + r0 - T; b = Jᵀ W e (n_a, 8) and vᵀWv.
                dof_a = dof[a]
                Q = np.empty((3, na, npx), np.float32)
                e = Q[2]
                np.multiply(S, gain[a, None].astype(np.float32), out=e)
                e += offset[a, None].astype(np.float32)
                e -= Ta
                np.multiply(gxa, e, out=Q[0])
                np.multiply(gya, e, out=Q[1])
                Q2 = Q.reshape(3 * na, npx)
                b = np.empty((na, 8))
                b[:, [0, 3, 6]] = (Q2 @ basis_w[0]).reshape(3, na).T
                b[:, 1] = Q2[:na] @ basis_w[1]
                b[:, 2] = Q2[:na] @ basis_w[2]
                b[:, 4] = Q2[na : 2 * na] @ basis_w[1]
                b[:, 5] = Q2[na : 2 * na] @ basis_w[2]
                b[:, 7] = np.einsum("np,np->n", Twa, e)
                ew = e if weight_sigma is None else e * wpx
                vv = np.einsum("np,np->n", ew, e).astype(np.float64)
                b67, vv0 = b[:, 6:8].copy(), vv
                Ninv_a = Ninv[a]
                if so.any():
                    # Still shift-only on the full grid: the 4 × 4 sub-block's inverse.
                    k = np.flatnonzero(so)
                    blk = np.zeros((len(k), 8, 8))
                    blk[:, np.ix_(sub, sub)[0], np.ix_(sub, sub)[1]] = inverse_blocks(
                        N[a[k]][:, sub][:, :, sub], pd[a[k]]
                    )
                    Ninv_a[k] = blk
                if lines is not None:
                    Ninv_a, jv, mis = line_update(Ninv_a, Aa, ln_n[a], ln_d[a], uv[a], w_line)
                    b = b + (w_line * mis)[:, None] * jv
                    vv = vv + w_line * mis * mis
                dq = np.einsum("nij,nj->ni", Ninv_a, b)
            ok_step = np.isfinite(dq).all(axis=1)
            dq[~ok_step] = 0.0
            # Compose W <- W ∘ ΔW⁻¹ with ΔW(x) = Δt + (I + ΔA) x; radiometry likewise.
            An, step = compose_inverse(A_s, dq)
            uv_new = uv_s - step
            change = uv_new - uv[a]  # of the estimate since the last iteration
            uv[a] = uv_new
            A[a] = An
            den = 1.0 + dq[:, 7]
            den = np.where(np.abs(den) > 1e-6, den, 1.0)
            gain[a] /= den
            offset[a] = (offset[a] - dq[:, 6]) / den
            iters[a] += 1
            it_left[a] -= 1
            # Precision from this linearisation: σ0² = vᵀv / (n - u), Σ = σ0² N⁻¹.
            vtv = vv - np.einsum("ni,ni->n", dq, b)
            sigma0[a] = np.sqrt(np.maximum(vtv, 0.0) / dof_a)

            conv = np.all(np.abs(change) < tol_px, axis=1) & ~so
            leave = so & (np.all(np.abs(change) < 1.0, axis=1) | (iters[a] >= 3))
            shift_only[a[leave]] = False
            drift = np.hypot(*(uv_new - uv_s0[a]).T) > max_shift_px
            # Footprint of the warped patch: half-extent per axis, pixels.
            ext = half * np.abs(An).sum(axis=2)
            e_lo, e_hi = uv_new - ext, uv_new + ext
            in_img = np.all((e_lo >= img_lo) & (e_hi <= img_hi), axis=1)
            in_win = np.all((e_lo >= w_lo[wrow]) & (e_hi <= w_hi[wrow]), axis=1)
            sc = np.abs(An[:, 0, 0] * An[:, 1, 1] - An[:, 0, 1] * An[:, 1, 0])
            g = gain[a]
            degen = ~ok_step | (sc < 0.25) | (sc > 4.0) | (g < 0.1) | (g > 10.0) | flat
            st = np.full(na, Status.NOT_CONVERGED, dtype=np.int8)
            st[conv] = Status.OK
            st[drift] = Status.OUT_OF_SEARCH
            st[degen] = Status.DEGENERATE
            st[~in_img] = Status.OUT_OF_IMAGE
            status[a] = st
            if conv.any():
                # Report the radiometry as the symmetric fit T ≈ r1 S + r0 (spread
                # ratio): the inverse compositional r1 regresses T on S, biased by noise.
                k = a[conv]
                if weight_sigma is None:
                    # Mean and spread of S = (e + T - r0) / r1 from Σe, ΣTe, Σe² (b, vv).
                    m_et = b67[conv, 0] / npx + t_mean[k]
                    v_et = (vv0[conv] + 2.0 * b67[conv, 1] + t_sq[k]) / npx - m_et**2
                    go = np.where(np.abs(g_old[conv]) > 1e-9, g_old[conv], 1e-9)
                    s_mean = (m_et - o_old[conv]) / go
                    s_sd = np.sqrt(np.maximum(v_et, 0.0)) / np.abs(go)
                else:
                    s_mean, s_sd = row_mean_sd(S[conv])
                g1 = np.where(s_sd > FLAT_SD, t_sd[k] / np.maximum(s_sd, FLAT_SD), gain[k])
                offset[k] = t_mean[k] - g1 * s_mean
                gain[k] = g1
            going = st == Status.NOT_CONVERGED
            left = it_left[a] > 0
            rewindow.append(a[going & ~in_win & left])
            keep = going & in_win & left
            if not keep.all():
                a, wrow = a[keep], wrow[keep]
                Ta, gxa, gya = Ta[keep], gxa[keep], gya[keep]
                Twa = Ta if weight_sigma is None else Twa[keep]
        todo = np.sort(np.concatenate(rewindow))

    # Covariance of the matched point: Σ = σ0² N⁻¹ (shifts), mapped by the affine part.
    done = np.flatnonzero(np.isfinite(sigma0))
    Nd = Ninv[done]
    if lines is not None and done.size:
        Nd, jv, _ = line_update(Nd, A[done], ln_n[done], ln_d[done], uv[done], w_line)
    if weight_sigma is not None and done.size:
        M2 = N2[done]
        if lines is not None:
            M2 = M2 + w_line * jv[:, :, None] * jv[:, None, :]
        Nd = Nd @ M2 @ Nd
    ct = Nd[:, [0, 3]][:, :, [0, 3]]
    Ad = A[done]
    # σ0 measures the noise of T plus that of the resampled S, which resampling has
    # reduced (averaged neighbours) without reducing its effect on the match.  With
    # equal noise in both images, the noise that enters the shifts is σ0² κ with
    # κ = (1 + r1²) / (1 + r1² ρ), ρ the mean variance factor of the resampling over
    # the patch at the match (:func:`resampling_noise_factor`).
    sub_grid = np.stack(np.meshgrid(*2 * [np.linspace(-half, half, 5)]), 0).reshape(2, -1)
    pos = uv[done, :, None] + Ad @ sub_grid  # (n_d, 2, 25): a 5 × 5 subgrid
    rho = resampling_noise_factor(pos[:, 0], pos[:, 1], upsample).mean(axis=1)
    g2 = gain[done] ** 2
    kappa = (1.0 + g2) / (1.0 + g2 * rho)
    cov[done] = (kappa * sigma0[done] ** 2)[:, None, None] * (Ad @ ct @ Ad.transpose(0, 2, 1))
    sig = np.sqrt(np.abs(np.diagonal(cov, axis1=1, axis2=2)))
    big = (status == Status.OK) & ~(np.all(sig <= max_sigma_px, axis=1))
    status[big] = Status.LARGE_SIGMA
    return LSMResult(
        uv=uv,
        affine=A,
        gain=gain,
        offset=offset,
        sigma0=sigma0,
        cov_uv=cov,
        iterations=iters,
        status=status,
        texture=texture,
    )
