"""Ellipsoidal metaballs rigidly attached to the skeleton's bones (paper 1, section 3.4).

Each metaball m sits in the anatomical frame of one bone at a fixed position along it
(``center0``, scaled by the scale group of the bone's length) with a fixed orientation
``rot`` and free radii ``radii = (lx, ly, lz)``.  For a world point x, with
``y = R_mᵀ (x − c_m)`` its coordinates in the metaball's frame,

    d_m = (y_x/lx)² + (y_y/ly)² + (y_z/lz)²        (eq. 7)
    f_m = exp(−2 d_m)                               (eq. 8, w = 1)
    F(x) = Σ_m f_m,   surface  F(x) = 0.5           (eq. 5, 15)

A lone metaball's visible surface is the ellipsoid with semi-axes ``sqrt(ln 2 / 2)·l``
(≈ 0.589 l).  An attractor observation (eq. 15) sums over the metaballs of the body
part the point was assigned to; the whole-body surface sums over all.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .skeleton import Pose, Skeleton, bone_frames
from .vec3 import sum3

#: Field threshold of the surface ``Σ f = T``.
THRESHOLD = 0.5
#: Visible radius over radius of a lone metaball: ``sqrt(ln 2 / 2)``.
VISIBLE = float(np.sqrt(np.log(2.0) / 2.0))

#: Limb segments of the simplified model (three metaballs each, as in the paper).
LIMB_BONES = (
    "l_shoulder",
    "l_elbow",
    "r_shoulder",
    "r_elbow",
    "l_hip",
    "l_knee",
    "r_hip",
    "r_knee",
)

#: Visible half-thickness (metres) of each bone's flesh: (across x, across y) for the
#: template body; the along-bone radius follows from the bone length and the count.
_THICKNESS = {
    "lowerback": (0.14, 0.10),
    "spine": (0.14, 0.10),
    "chest": (0.15, 0.11),
    "neck": (0.05, 0.05),
    "head": (0.08, 0.09),
    "l_clavicle": (0.05, 0.06),
    "r_clavicle": (0.05, 0.06),
    "l_shoulder": (0.05, 0.05),
    "r_shoulder": (0.05, 0.05),
    "l_elbow": (0.04, 0.04),
    "r_elbow": (0.04, 0.04),
    "l_wrist": (0.02, 0.04),
    "r_wrist": (0.02, 0.04),
    "l_hip": (0.08, 0.08),
    "r_hip": (0.08, 0.08),
    "l_knee": (0.055, 0.055),
    "r_knee": (0.055, 0.055),
    "l_ankle": (0.045, 0.05),
    "r_ankle": (0.045, 0.05),
}


@dataclass
class Metaballs:
    """M metaballs.

    Attributes
    ----------
    bone : (M,) int — carrying bone (index into ``Skeleton.bone_names``)
    center0 : (M, 3) — centre in the bone's anatomical frame, metres before scaling
    group : (M,) int — scale group multiplying ``center0`` (−1: none)
    rot : (M, 3, 3) — orientation of the metaball's axes in the bone's anatomical frame
    radii : (M, 3) — ``(lx, ly, lz)``, metres (> 0)
    visible_scale : (M, 3) or None — the rendered ellipsoid of each metaball (contours,
        camera selection, segmentation) has semi-axes ``radii · visible_scale``; None:
        ``VISIBLE``, a lone metaball's iso-surface.  A deflated template
        (:func:`deflate`) keeps its rendered ellipsoids where the body's flesh is while
        its blended surface ``Σ f = 0.5`` follows them (one surface for all terms).
    """

    bone: np.ndarray
    center0: np.ndarray
    group: np.ndarray
    rot: np.ndarray
    radii: np.ndarray
    visible_scale: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.bone)

    @property
    def vscale(self) -> np.ndarray:
        """(M, 3) rendered semi-axes over radii (``VISIBLE`` unless deflated)."""
        if self.visible_scale is None:
            return np.full(self.radii.shape, VISIBLE)
        return self.visible_scale

    @property
    def visible(self) -> np.ndarray:
        """(M, 3) semi-axes of the rendered ellipsoids, metres."""
        return self.radii * self.vscale

    def with_parts(self, center0: np.ndarray, radii: np.ndarray) -> Metaballs:
        """The same metaballs with other centres (M, 3) and radii (M, 3)."""
        return Metaballs(
            self.bone,
            np.asarray(center0, float),
            self.group,
            self.rot,
            np.asarray(radii, float).reshape(-1, 3),
            self.visible_scale,
        )

    def copy(self, radii: np.ndarray | None = None) -> Metaballs:
        vs = None if self.visible_scale is None else self.visible_scale.copy()
        return Metaballs(
            self.bone.copy(),
            self.center0.copy(),
            self.group.copy(),
            self.rot.copy(),
            self.radii.copy()
            if radii is None
            else np.asarray(radii, dtype=float).reshape(-1, 3).copy(),
            vs,
        )

    def to_dict(self, skel: Skeleton) -> list[dict]:
        """JSON-able list (bones by name), see :mod:`core.state`."""
        out = [
            {
                "bone": skel.bone_names[int(self.bone[m])],
                "center": self.center0[m].tolist(),
                "scale_group": int(self.group[m]),
                "rotation": self.rot[m].round(15).tolist(),
                "radii": self.radii[m].tolist(),
            }
            for m in range(len(self))
        ]
        if self.visible_scale is not None:
            for m, item in enumerate(out):
                item["visible_scale"] = self.visible_scale[m].tolist()
        return out

    @classmethod
    def from_dict(cls, items: list[dict], skel: Skeleton) -> Metaballs:
        """Inverse of :meth:`to_dict` (KeyError / ValueError on malformed input)."""
        return cls(
            bone=np.array([skel.bone_index(str(v["bone"])) for v in items], dtype=int),
            center0=np.array([v["center"] for v in items], dtype=float).reshape(-1, 3),
            group=np.array([int(v["scale_group"]) for v in items], dtype=int),
            rot=np.array([v["rotation"] for v in items], dtype=float).reshape(-1, 3, 3),
            radii=np.array([v["radii"] for v in items], dtype=float).reshape(-1, 3),
            visible_scale=(
                np.array([v["visible_scale"] for v in items], dtype=float).reshape(-1, 3)
                if items and "visible_scale" in items[0]
                else None
            ),
        )


def make_metaballs(
    skel: Skeleton,
    model: str = "simplified",
    s: np.ndarray | None = None,
    per_limb: int | None = None,
) -> Metaballs:
    """Default metaballs along every bone.

    Parameters
    ----------
    model : ``"simplified"`` (three per limb segment, one or two elsewhere, as in the
        paper) or ``"complete"`` (six per limb segment, three elsewhere).
    s : (G,) scale coefficients, used to size the along-bone radii (default ones).
    per_limb : overrides the count per limb segment.

    Returns
    -------
    Metaballs
        Centres evenly spaced from head to tail, axes aligned with the bone's
        anatomical frame rotated so that local z runs along the bone.
    """
    if model not in ("simplified", "complete"):
        raise ValueError(f"unknown metaball model {model!r}")
    s = np.ones(skel.n_groups) if s is None else np.asarray(s, dtype=float)
    n_limb = per_limb or (3 if model == "simplified" else 6)
    n_other = 1 if model == "simplified" else 3
    bone, center, group, rot, radii = [], [], [], [], []
    for b, name in enumerate(skel.bone_names):
        tail = skel.joint_index(skel.bone_tail[b])
        if name == "pelvis":  # the hip girdle, off the hip axis so that it fixes the root
            hip = skel.joint_offset[skel.joint_index("l_hip")]
            w = float(np.linalg.norm(hip))
            hg = int(skel.joint_group[skel.joint_index("l_hip")])
            # laid out along the drop from the pelvis to the hips: turned about the
            # lateral axis so that −z runs towards the hips' line where the hips sit in
            # front of (or behind) the pelvis (``SequenceSettings.hip_lean``; without
            # the turn the girdle hung behind the hips, and jumps_line3 lost its hidden
            # right leg: 27 mm); hips on the pelvis' plane leave it as it is (Q = I)
            a = float(np.arctan2(hip[1], -hip[2])) if hip[2] < 0 else 0.0
            c, sn = np.cos(a), np.sin(a)
            Q = np.array([[1, 0, 0], [0, c, -sn], [0, sn, c]]) if a else np.eye(3)
            for cx in (0.0,) if model == "simplified" else (-0.5, 0.0, 0.5):
                bone.append(b)
                center.append(Q @ np.array([cx * w, 0.01, -0.04]))
                group.append(hg)
                rot.append(Q)
                radii.append((0.16 / VISIBLE, 0.10 / VISIBLE, 0.09 / VISIBLE))
            continue
        if skel.joint_bone[tail] != b:
            continue
        off = skel.joint_offset[tail]
        g = int(skel.joint_group[tail])
        length = float(np.linalg.norm(off) * (s[g] if g >= 0 else 1.0))
        if length < 1e-6:
            continue
        n = n_limb if name in LIMB_BONES else n_other
        if name in ("lowerback", "spine", "chest") and model == "simplified":
            n = 2
        R = _align_z(off)
        tx, ty = _THICKNESS.get(name, (0.05, 0.05))
        lz = max(length / n, 0.02) / VISIBLE * 0.75
        for i in range(n):
            t = (i + 0.5) / n
            bone.append(b)
            center.append(off * t)
            group.append(g)
            rot.append(R)
            radii.append((tx / VISIBLE, ty / VISIBLE, lz))
    return Metaballs(
        np.array(bone, dtype=int),
        np.array(center, dtype=float),
        np.array(group, dtype=int),
        np.array(rot),
        np.array(radii, dtype=float),
    )


def _align_z(direction: np.ndarray) -> np.ndarray:
    """Rotation whose z column is along ``direction``, x as close as possible to +X."""
    z = direction / np.linalg.norm(direction)
    ref = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, -1.0, 0.0])
    x = ref - z * (ref @ z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def world_frames(skel: Skeleton, pose: Pose, balls: Metaballs, s: np.ndarray, which=None):
    """World rotation (F, M, 3, 3) and centre (F, M, 3) of every metaball, or of the
    metaballs ``which`` (indices or a bool mask (M,)) only: (F, M', ...), the same bits,
    from the frames of their bones alone (``pose`` may hold only those:
    :func:`core.skeleton.forward`'s ``dofs``)."""
    group, bone, rot, c0 = balls.group, balls.bone, balls.rot, balls.center0
    if which is None:
        Rb, pb = bone_frames(skel, pose)
    else:
        group, bone, rot, c0 = group[which], bone[which], rot[which], c0[which]
        used, bone = np.unique(bone, return_inverse=True)
        Rb = pose.R[:, skel.bone_dof[used]] @ skel.bone_post[used][None]
        pb = pose.p[:, skel.bone_dof[used]]
    scale = np.where(group >= 0, np.asarray(s, float)[np.maximum(group, 0)], 1.0)
    c = c0 * scale[:, None]
    Rw = Rb[:, bone] @ rot[None]
    cw = np.einsum("fmij,mj->fmi", Rb[:, bone], c) + pb[:, bone]
    return Rw, cw


def local_coords(x: np.ndarray, Rw: np.ndarray, cw: np.ndarray) -> np.ndarray:
    """Points (N, 3) in every metaball's frame, ``Rwᵀ (x − c)``: (N, M, 3) metres, for
    one frame's ``Rw`` (M, 3, 3) and ``cw`` (M, 3).

    One matrix product for all metaballs, ``x · [Rw_1 … Rw_M]`` less each centre's
    image ``c_m · Rw_m`` (a (N, 3) by (3, 3M) product: about 5× faster than a batched
    product per metaball and its transposed copy).
    """
    x = np.asarray(x, float).reshape(-1, 3)
    Rw = np.asarray(Rw, float)
    M = len(Rw)
    A = Rw.transpose(1, 0, 2).reshape(3, 3 * M)  # A[i, 3m + j] = Rw[m, i, j]
    off = np.einsum("mi,mij->mj", np.asarray(cw, float), Rw)
    return (x @ A).reshape(len(x), M, 3) - off[None]


def field(
    x: np.ndarray,
    Rw: np.ndarray,
    cw: np.ndarray,
    radii: np.ndarray,
    member: np.ndarray | None = None,
):
    """Field value and gradient at points of one frame.

    Parameters
    ----------
    x : (N, 3) world points, metres
    Rw, cw : (M, 3, 3), (M, 3) metaball world frames of this frame
    radii : (M, 3)
    member : (N, M) bool, optional — which metaballs count for each point (its body
        part); all when omitted.

    Returns
    -------
    F : (N,) field value ``Σ f_m``
    grad : (N, 3) ``∂F/∂x``, 1/metre
    f : (N, M) the individual terms (zero where not a member)
    y : (N, M, 3) the point in each metaball's frame
    """
    y = local_coords(x, Rw, cw)
    q = y / radii[None] ** 2  # (N, M, 3)
    d = sum3(y * q)
    f = np.exp(-2.0 * np.minimum(d, 700.0))
    if member is not None:
        f = f * member
    F = f.sum(axis=1)
    # ∂F/∂x = −4 Σ_m f_m Rw_m q_m: one (N, 3M) by (3M, 3) product
    B = np.asarray(Rw, float).transpose(0, 2, 1).reshape(-1, 3)  # B[3m + j, i] = Rw[m, i, j]
    grad = -4.0 * (f[..., None] * q).reshape(len(f), -1) @ B
    return F, grad, f, y


def normals(grad: np.ndarray) -> np.ndarray:
    """Outward unit surface normals (N, 3) from field gradients (the field falls outward)."""
    n = -grad
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300)


def radius_jacobian(f: np.ndarray, y: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """``∂F/∂radii`` (N, M, 3): ``4 f_m y_a² / l_a³``."""
    return 4.0 * f[..., None] * y**2 / radii[None] ** 3


def pose_jacobian(
    skel: Skeleton,
    pose_f: Pose,
    balls: Metaballs,
    s: np.ndarray,
    x: np.ndarray,
    f: np.ndarray,
    y: np.ndarray,
    radii: np.ndarray,
    frame: int = 0,
    anc: np.ndarray | None = None,
):
    """Jacobians of the field at fixed world points w.r.t. pose and scales.

    Moving a metaball by a small rotation ``δθ_k`` about axis ``ω_k`` through ``p_k``
    changes its local coordinates by ``−R_mᵀ (ω_k × (x − p_k)) δθ_k``; translating the
    root by ``δt`` changes them by ``−R_mᵀ δt``; and a scale change moves the centre.

    Parameters
    ----------
    pose_f : Pose of (at least) the frame ``frame``
    x : (N, 3) points; f, y : from :func:`field` for the same frame

    Returns
    -------
    J_theta : (N, n) ``∂F/∂θ``
    J_root : (N, 3) ``∂F/∂root_xyz``
    J_s : (N, G) ``∂F/∂s``
    """
    anc = skel.ancestors() if anc is None else anc
    Rw, _ = world_frames(skel, one_frame(pose_f, frame), balls, s)
    Rw = Rw[0]
    q = y / radii[None] ** 2
    gm = -4.0 * f[..., None] * np.einsum("mij,nmj->nmi", Rw, q)  # (N, M, 3): ∂f_m/∂x
    dof_of = skel.bone_dof[balls.bone]  # (M,)
    mask = anc[dof_of].astype(float)  # (M, n)
    w = pose_f.axes[frame]  # (n, 3)
    pk = pose_f.p[frame]  # (n, 3)
    dx = x[:, None, :] - pk[None]  # (N, n, 3)
    # ∂f_m/∂θ_k = −gm · (ω_k × (x − p_k)) = −(x − p_k) · (gm × ω_k); metaballs of one
    # bone share their ancestors, so sum their gradients first (memory O(N·n) per bone)
    J_theta = np.zeros((len(x), skel.n_dof))
    for b in np.unique(balls.bone):
        on = balls.bone == b
        rows = np.nonzero(np.any(f[:, on] != 0.0, axis=1))[0]  # points this bone touches
        if len(rows) == 0:
            continue
        gb = gm[rows][:, on].sum(axis=1)  # (N_b, 3)
        cols = np.nonzero(anc[skel.bone_dof[b]])[0]
        gxw = np.cross(gb[:, None, :], w[None, cols])  # (N_b, K, 3)
        J_theta[np.ix_(rows, cols)] -= np.einsum("nki,nki->nk", gxw, dx[rows][:, cols])
    J_root = -gm.sum(axis=1)
    # scales: centre c_m moves by Σ_{k anc, group g} R_par(k) o_k + [g_m = g] R_b c0_m
    G = skel.n_groups
    off_world = np.einsum("kij,kj->ki", pose_f.R_parent[frame], skel.dof_offset)
    onehot = np.zeros((skel.n_dof, G))
    has = skel.dof_group >= 0
    onehot[np.nonzero(has)[0], skel.dof_group[has]] = 1.0
    dc = np.einsum("mk,ki,kg->mig", mask, off_world, onehot)  # (M, 3, G)
    Rb, _ = bone_frames(skel, one_frame(pose_f, frame))
    own = np.einsum("mij,mj->mi", Rb[0, balls.bone], balls.center0)
    sel = np.nonzero(balls.group >= 0)[0]
    dc[sel, :, balls.group[sel]] += own[sel]
    J_s = -np.einsum("nmi,mig->ng", gm, dc)
    return J_theta, J_root, J_s


def one_frame(pose: Pose, frame: int) -> Pose:
    """Frame ``frame`` of ``pose`` as a one-frame :class:`Pose` (views, no copy)."""
    return Pose(
        R=pose.R[frame : frame + 1],
        p=pose.p[frame : frame + 1],
        R_parent=pose.R_parent[frame : frame + 1],
    )
