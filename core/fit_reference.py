"""The texture reference of the flow: the clicked frame's texture, matched into later frames.

Corners lost and lifted again carry the pose error of the frame they are lifted at,
so on a rig without 3-D points an error, once made, stays (:mod:`core.fit_flow`).  The
reference holds the clicked frame's texture: its corners are lifted onto the clicked
pose (:meth:`core.fit_flow.FlowAnchors.set_reference`, which hands them to
:meth:`TextureReference.start`) and, in every later frame where the last fitted pose
shows them (:meth:`TextureReference.see`), matched by least squares
(:func:`core.lsm.match`, affine + radiometric) from the clicked frame's image into the
new one (:meth:`TextureReference.matches`).  Each starts at its own last match (else
at its projection on the last fitted pose), moved by the image's motion between the
neighbouring frames (Lucas–Kanade), with the affine part the model predicts from the
surface's tangents (:func:`surface_tangents`, :func:`local_affine`) or its last
match's.  A corner whose match lies more than ``reference_drop_px`` from its
projection on a frame's accepted fit (a false lock on like texture, or a point hidden
behind a part the model misplaces) is not matched again.

Two opt-in extensions, measured and not kept (docs/design.md, "Reference corners
matched in the other cameras, and their depths refined"): matching each corner in the
other cameras where the body shows it from a like direction (``reference_across``),
and refining each corner's depth along its clicked ray from its matches
(``reference_depth``).

Frames: world Z up, metres; image pixels with integer coordinates at pixel centres;
bone-fixed points in their bone's frame, metres.
"""

from __future__ import annotations

import numpy as np

from .camera import Camera, camera_project_jacobians
from .image_stack import ImageStack
from .skeleton import Skeleton, bone_frames


def visible_points(skel: Skeleton, pose, camera: Camera, ren, bone, q0, depth_tol: float):
    """Which bone-fixed points (``bone`` (K,), ``q0`` (K, 3) metres) are seen in a
    render: ``(uv (K, 2) pixels, seen (K,) bool)`` — projected inside the image onto
    their own part, no more than ``depth_tol`` metres behind its rendered surface."""
    Rb, pb = bone_frames(skel, pose)
    x = pb[0, bone] + np.einsum("nij,nj->ni", Rb[0, bone], q0)
    uv = camera.project(x)
    w, h = camera.size
    inside = np.all(np.isfinite(uv), axis=1)
    inside &= (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
    seen = np.zeros(len(bone), bool)
    if inside.any():
        iu = np.rint(uv[inside, 0]).astype(int)
        iv = np.rint(uv[inside, 1]).astype(int)
        dist = np.linalg.norm(x[inside] - camera.center, axis=1)
        seen[inside] = (ren.part_id[iv, iu] == bone[inside]) & (
            dist <= ren.depth[iv, iu] + depth_tol
        )
    return uv, seen


def surface_tangents(skel: Skeleton, pose, camera: Camera, ren, uv, bone):
    """The rendered surface's offsets (K, 2, 3), metres in the bone's frame, that a
    step of one pixel along u and along v from ``uv`` (K, 2) covers (central
    differences of the z-buffer's surface points; where a neighbour is not on the
    same part, the step perpendicular to the ray at the point's depth)."""
    Rb, pb = bone_frames(skel, pose)
    w, h = camera.size
    iu = np.clip(np.rint(uv[:, 0]).astype(int), 1, w - 2)
    iv = np.clip(np.rint(uv[:, 1]).astype(int), 1, h - 2)
    out = np.zeros((len(uv), 2, 3))
    for a, (du, dv) in enumerate(((1, 0), (0, 1))):
        ends = []
        for sgn in (-1, 1):
            ju, jv = iu + sgn * du, iv + sgn * dv
            z = ren.depth[jv, ju]
            flat = ~np.isfinite(z) | (ren.part_id[jv, ju] != bone)
            z = np.where(flat, ren.depth[iv, iu], z)
            _, d = camera.rays(np.stack([ju, jv], 1).astype(float))
            ends.append(camera.center + z[:, None] * d)
        out[:, a] = np.einsum("nji,nj->ni", Rb[0, bone], (ends[1] - ends[0]) / 2.0)
    return out


def local_affine(skel: Skeleton, pose, camera: Camera, bone, q0, tangents):
    """The image of a template pixel step (K, 2, 2): columns the projected moves of
    the bone-fixed points ``q0`` (K, 3) along ``tangents`` (K, 2, 3) in ``pose``
    (central differences, pixels per pixel) — LSM's start of the affine part."""
    Rb, pb = bone_frames(skel, pose)
    A = np.zeros((len(bone), 2, 2))
    for a in range(2):
        ends = [
            camera.project(
                pb[0, bone] + np.einsum("nij,nj->ni", Rb[0, bone], q0 + sgn * tangents[:, a])
            )
            for sgn in (-1, 1)
        ]
        A[:, :, a] = (ends[1] - ends[0]) / 2.0
    return A


class TextureReference:
    """The clicked frame's corners, with their state per (reference camera, camera).

    Parameters
    ----------
    cameras : list (C) of Camera
    image : callable ``(camera index, frame) -> (H, W) uint8`` grey image
    settings : :class:`core.fit_flow.FlowSettings` (its ``reference_*`` fields)
    follow : callable ``(img0, img1, uv (K, 2)) -> (uv1 (K, 2), ok (K,))``, the image
        motion of points between two frames of one camera (Lucas–Kanade)

    Attributes
    ----------
    ref : per camera (image, uv (M, 2), bone (M,), q0 (M, 3), tangents (M, 2, 3)) of
        the reference frame
    alive : {(reference camera, camera): (M,) bool} — not dropped
    seen : per pair (c, d, index into ref[c], uv and affine start) at the stored frame
    matched : {frame: {(c, d): (index, uv, affine)}} matched there
    depth : per reference camera (ray (M, 3) in the bone's frame, Σ JᵀJ (M,),
        Σ Jᵀ(r + J t) (M,), depth t (M,) metres) of its corners
    """

    def __init__(self, cameras: list[Camera], image, settings, follow):
        self.cameras = list(cameras)
        self.image = image
        self.cfg = settings
        self.follow = follow
        self.ref: list = []
        self.stack: ImageStack | None = None
        self.alive: dict = {}
        self.seen: list = []
        self.matched: dict = {}
        self.depth: list = []

    def start(self, skel: Skeleton, pose, lifted: list) -> None:
        """Keep ``lifted``, per camera (image, uv, bone, q0, tangents) of the clicked
        frame's corners on the fitted ``pose``, as the reference."""
        self.ref, self.alive, self.depth = list(lifted), {}, []
        Rb, _ = bone_frames(skel, pose)
        for cam, (_, uv, bone, _, _) in zip(self.cameras, self.ref, strict=True):
            _, ray = cam.rays(uv)
            ray = np.einsum("nji,nj->ni", Rb[0, bone], ray.reshape(-1, 3))
            m = len(bone)
            self.depth.append((ray, np.zeros(m), np.zeros(m), np.zeros(m)))
        self.stack = ImageStack([r[0] for r in self.ref])  # its upsampled copy kept
        for c, ref in enumerate(self.ref):
            for d in range(len(self.cameras)):
                if d == c or self.cfg.reference_across:
                    self.alive[c, d] = np.ones(len(ref[2]), bool)

    def clear(self) -> None:
        """Forget the stored frame's corners (the reference itself stays)."""
        self.seen = []
        self.matched = {}

    def update(self, skel: Skeleton, pose, rens: list, matched: dict | None) -> None:
        """After a frame's accepted fit ``pose`` (``rens`` its part render per camera,
        ``matched`` the frame's matches or None): refine the depths (with
        ``reference_depth``) and keep the corners it shows for the next frame."""
        if self.cfg.reference_depth and matched is not None:
            self.refine_depths(skel, pose, matched)
        for c, d in self.alive:
            self.see(skel, pose, rens[d], c, d, matched)

    def points(self, c: int) -> np.ndarray:
        """Reference camera c's surface points (M, 3) in their bones' frames, metres,
        moved along their clicked rays by the refined depths."""
        q0 = self.ref[c][3]
        ray, _, _, t = self.depth[c]
        return q0 + t[:, None] * ray

    def refine_depths(self, skel: Skeleton, pose, matched: dict) -> None:
        """Add the frame's matches (``matched`` {(c, d): (index, uv, affine)}) at the
        accepted ``pose`` to each corner's 1-D normal equation for its depth along its
        clicked ray, and solve it (a prior of σ ``reference_depth_prior_m`` towards
        the lifted depth)."""
        Rb, pb = bone_frames(skel, pose)
        gate = self.cfg.reference_depth_gate_px
        lam = 1.0 / self.cfg.reference_depth_prior_m**2  # px² / m² for a 1 px match
        for (c, d), (idx, muv, _) in matched.items():
            if not len(idx):
                continue
            ray, N, B, t = self.depth[c]
            bone = self.ref[c][2][idx]
            x = pb[0, bone] + np.einsum("nij,nj->ni", Rb[0, bone], self.points(c)[idx])
            uv, _, Jx = camera_project_jacobians(self.cameras[d], x)
            J = np.einsum("nij,nj->ni", Jx, np.einsum("nij,nj->ni", Rb[0, bone], ray[idx]))
            r = muv - uv
            ok = np.all(np.isfinite(r), axis=1) & (np.linalg.norm(r, axis=1) <= gate)
            i, J, r = idx[ok], J[ok], r[ok]
            np.add.at(N, i, np.sum(J * J, axis=1))
            np.add.at(B, i, np.sum(J * (r + J * t[i, None]), axis=1))
        lim = self.cfg.reference_depth_max_m
        for _, N, B, t in self.depth:
            t[:] = np.clip(B / (N + lam), -lim, lim)

    def see(self, skel, pose, ren, c, d, matched) -> None:
        """Keep the reference corners of camera c that the fitted ``pose`` shows camera
        d (``ren`` its part render) for matching into the next frame, each with its
        start: its match in this frame (``matched``) where there is one, else its
        projection; corners matched too far from the projection are dropped for good."""
        cam = self.cameras[d]
        _, _, bone, _, tan = self.ref[c]
        q0 = self.points(c)
        alive = self.alive[c, d]
        uv, seen = visible_points(skel, pose, cam, ren, bone, q0, self.cfg.reference_depth_m)
        i = np.flatnonzero(seen & alive)
        A = local_affine(skel, pose, cam, bone[i], q0[i], tan[i])
        uv = uv[i]
        if d != c:  # another camera: only where it sees the surface as c did
            sv = np.linalg.svd(A, compute_uv=False)
            k = self.cfg.reference_across_stretch
            like = (sv[:, 0] <= k) & (sv[:, 1] >= 1.0 / k) & (sv[:, 0] <= k * sv[:, 1])
            Rb, pb = bone_frames(skel, pose)
            b = bone[i]
            ray = np.einsum("nij,nj->ni", Rb[0, b], self.depth[c][0][i])  # clicked
            x = pb[0, b] + np.einsum("nij,nj->ni", Rb[0, b], q0[i])
            view = x - cam.center
            cos = np.sum(ray * view, axis=1) / np.linalg.norm(view, axis=1)
            like &= cos >= np.cos(np.radians(self.cfg.reference_across_deg))
            i, uv, A = i[like], uv[like], A[like]
        prev = None if matched is None else matched.get((c, d))
        if prev is not None and len(prev[0]):  # start where matched
            mi, muv, mA = prev
            at = np.searchsorted(mi, i)
            hit = (at < len(mi)) & (mi[np.minimum(at, len(mi) - 1)] == i)
            drop = self.cfg.reference_drop_px
            if drop is not None:
                off = np.zeros(len(i), bool)
                off[hit] = np.linalg.norm(uv[hit] - muv[at[hit]], axis=1) > drop
                alive[i[off]] = False
                keep = ~off
                i, uv, A, hit, at = i[keep], uv[keep], A[keep], hit[keep], at[keep]
            uv[hit], A[hit] = muv[at[hit]], mA[at[hit]]
        self.seen.append((c, d, i, uv, A))

    def matches(self, stored: int, frame: int):
        """The reference corners seen at frame ``stored``, matched into ``frame``:
        per camera ``(camera, bone (K,), q0 (K, 3), uv (K, 2))``.  Each starts at its
        match in the stored frame (else its projection on the stored pose) moved as the
        image moved there (Lucas–Kanade between the neighbouring frames), with that
        match's affine part (else the model's), and is matched by least squares from
        the reference frame's image (of its own camera or, ``reference_across``,
        another's)."""
        from .lsm import match

        pairs = [p for p in self.seen if len(p[2])]
        self.matched[frame] = matched = {}
        if not pairs:
            return []
        cams = sorted({p[1] for p in pairs})
        starts = [None] * len(pairs)
        for d in cams:  # one Lucas–Kanade call per camera
            mine = [k for k, p in enumerate(pairs) if p[1] == d]
            guess = np.concatenate([pairs[k][3] for k in mine])
            moved, ok = self.follow(self.image(d, stored), self.image(d, frame), guess)
            moved = np.where(ok[:, None], moved, guess)
            at = np.cumsum([0] + [len(pairs[k][3]) for k in mine])
            for n, k in enumerate(mine):
                starts[k] = moved[at[n] : at[n + 1]]
        res = match(
            self.stack,
            ImageStack([self.image(d, frame) for d in cams]),
            np.concatenate([self.ref[c][1][idx] for c, _, idx, _, _ in pairs]),
            np.concatenate(starts),
            affine=np.concatenate([A for *_, A in pairs]),
            template_index=np.concatenate([np.full(len(p[2]), p[0]) for p in pairs]),
            search_index=np.concatenate([np.full(len(p[2]), cams.index(p[1])) for p in pairs]),
            max_shift_px=self.cfg.reference_search_px,
            max_sigma_px=self.cfg.reference_max_sigma_px,
        )
        out, at = [], 0
        for c, d, idx, _, _ in pairs:
            sl = slice(at, at + len(idx))
            at += len(idx)
            k = res.status[sl] == 0
            bone, q0 = self.ref[c][2], self.points(c)
            out.append((d, bone[idx[k]], q0[idx[k]], res.uv[sl][k]))
            matched[c, d] = (idx[k], res.uv[sl][k], res.affine[sl][k])
        return out
