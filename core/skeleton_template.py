"""The default full-body template of the articulated skeleton (paper 1, §3).

Tables only: the scale groups, the bones with their parents, tail joints and
single-DOF axes, the rest offsets of a 1.70 m adult, soft joint limits (degrees) and
the σ of the stiffness and anchor priors (radians).  :func:`core.skeleton.make_skeleton`
builds a :class:`core.skeleton.Skeleton` from them.
"""

from __future__ import annotations

#: Scale groups: one coefficient each, multiplying the rest offsets of their links.
SCALE_GROUPS = (
    "trunk",
    "neck",
    "head",
    "clavicle",
    "upper_arm",
    "forearm",
    "hand",
    "hip_width",
    "thigh",
    "shin",
    "foot",
)

#: Bones: name -> (parent bone, tail joint, DOF axes).  Head joint = bone name,
#: except ``lowerback`` whose head is the pelvis.  Order: parents first.
BONES = {
    "pelvis": (None, "spine", "zxy"),
    "lowerback": ("pelvis", "spine", "xyz"),
    "spine": ("lowerback", "chest", "xyz"),
    "chest": ("spine", "neck", "xyz"),
    "neck": ("chest", "head", "xyz"),
    "head": ("neck", "head_top", "xy"),
    "l_clavicle": ("chest", "l_shoulder", "zy"),
    "l_shoulder": ("l_clavicle", "l_elbow", "xyz"),
    "l_elbow": ("l_shoulder", "l_wrist", "xz"),
    "l_wrist": ("l_elbow", "l_hand", "xy"),
    "r_clavicle": ("chest", "r_shoulder", "zy"),
    "r_shoulder": ("r_clavicle", "r_elbow", "xyz"),
    "r_elbow": ("r_shoulder", "r_wrist", "xz"),
    "r_wrist": ("r_elbow", "r_hand", "xy"),
    "l_hip": ("pelvis", "l_knee", "xyz"),
    "l_knee": ("l_hip", "l_ankle", "x"),
    "l_ankle": ("l_knee", "l_toe", "xz"),
    "r_hip": ("pelvis", "r_knee", "xyz"),
    "r_knee": ("r_hip", "r_ankle", "x"),
    "r_ankle": ("r_knee", "r_toe", "xz"),
}

#: Joints: name -> (bone whose anatomical frame carries it, scale group, rest offset in
#: that frame in metres, template of a 1.70 m adult).  The pelvis is the root origin.
TEMPLATE_JOINTS = {
    "pelvis": ("pelvis", None, (0.0, 0.0, 0.0)),
    "spine": ("lowerback", "trunk", (0.0, 0.0, 0.10)),
    "chest": ("spine", "trunk", (0.0, 0.0, 0.18)),
    "neck": ("chest", "trunk", (0.0, 0.0, 0.22)),
    "head": ("neck", "neck", (0.0, 0.0, 0.10)),
    "head_top": ("head", "head", (0.0, 0.0, 0.15)),
    "l_clavicle": ("chest", "clavicle", (0.02, 0.0, 0.17)),
    "l_shoulder": ("l_clavicle", "clavicle", (0.15, 0.0, 0.02)),
    "l_elbow": ("l_shoulder", "upper_arm", (0.0, 0.0, -0.29)),
    "l_wrist": ("l_elbow", "forearm", (0.0, 0.0, -0.25)),
    "l_hand": ("l_wrist", "hand", (0.0, 0.0, -0.08)),
    "r_clavicle": ("chest", "clavicle", (-0.02, 0.0, 0.17)),
    "r_shoulder": ("r_clavicle", "clavicle", (-0.15, 0.0, 0.02)),
    "r_elbow": ("r_shoulder", "upper_arm", (0.0, 0.0, -0.29)),
    "r_wrist": ("r_elbow", "forearm", (0.0, 0.0, -0.25)),
    "r_hand": ("r_wrist", "hand", (0.0, 0.0, -0.08)),
    "l_hip": ("pelvis", "hip_width", (0.09, 0.0, 0.0)),
    "l_knee": ("l_hip", "thigh", (0.0, 0.0, -0.42)),
    "l_ankle": ("l_knee", "shin", (0.0, 0.0, -0.41)),
    "l_toe": ("l_ankle", "foot", (0.0, -0.14, -0.06)),
    "r_hip": ("pelvis", "hip_width", (-0.09, 0.0, 0.0)),
    "r_knee": ("r_hip", "thigh", (0.0, 0.0, -0.42)),
    "r_ankle": ("r_knee", "shin", (0.0, 0.0, -0.41)),
    "r_toe": ("r_ankle", "foot", (0.0, -0.14, -0.06)),
}

#: Soft joint limits (radians) per DOF name; DOFs not listed are unlimited.
LIMITS = {
    "lowerback_x": (-60, 45),
    "lowerback_y": (-40, 40),
    "lowerback_z": (-45, 45),
    "spine_x": (-45, 30),
    "spine_y": (-30, 30),
    "spine_z": (-40, 40),
    "chest_x": (-45, 30),
    "chest_y": (-30, 30),
    "chest_z": (-40, 40),
    "neck_x": (-60, 60),
    "neck_y": (-45, 45),
    "neck_z": (-80, 80),
    "head_x": (-45, 45),
    "head_y": (-30, 30),
    "l_clavicle_z": (-30, 30),
    "l_clavicle_y": (-45, 20),
    "r_clavicle_z": (-30, 30),
    "r_clavicle_y": (-20, 45),
    "l_shoulder_x": (-180, 60),
    "l_shoulder_y": (-180, 30),
    "l_shoulder_z": (-100, 100),
    "r_shoulder_x": (-180, 60),
    "r_shoulder_y": (-30, 180),
    "r_shoulder_z": (-100, 100),
    "l_elbow_x": (-160, 5),
    "l_elbow_z": (-100, 100),
    "r_elbow_x": (-160, 5),
    "r_elbow_z": (-100, 100),
    "l_wrist_x": (-80, 80),
    "l_wrist_y": (-40, 40),
    "r_wrist_x": (-80, 80),
    "r_wrist_y": (-40, 40),
    "l_hip_x": (-130, 40),
    "l_hip_y": (-90, 30),
    "l_hip_z": (-60, 60),
    "r_hip_x": (-130, 40),
    "r_hip_y": (-30, 90),
    "r_hip_z": (-60, 60),
    "l_knee_x": (-5, 160),
    "r_knee_x": (-5, 160),
    "l_ankle_x": (-50, 50),
    "l_ankle_z": (-40, 40),
    "r_ankle_x": (-50, 50),
    "r_ankle_z": (-40, 40),
}


#: Stiffness of DOFs the surface hardly observes: the σ (radians) of a prior towards the
#: predicted angle that is never exceeded (twists of round parts, clavicles, the split
#: of a bend among the spine links, the hands).  DOFs not listed have no floor.
STIFF_SIGMA = {
    "l_clavicle_z": 0.03,
    "l_clavicle_y": 0.03,
    "r_clavicle_z": 0.03,
    "r_clavicle_y": 0.03,
    "lowerback_z": 0.04,
    "spine_z": 0.04,
    "chest_z": 0.04,
    "lowerback_x": 0.08,
    "lowerback_y": 0.08,
    "spine_x": 0.08,
    "spine_y": 0.08,
    "chest_x": 0.08,
    "chest_y": 0.08,
    "neck_x": 0.08,
    "neck_y": 0.08,
    "neck_z": 0.08,
    "head_x": 0.1,
    "head_y": 0.1,
    "l_wrist_x": 0.15,
    "l_wrist_y": 0.15,
    "r_wrist_x": 0.15,
    "r_wrist_y": 0.15,
    "l_elbow_z": 0.1,
    "r_elbow_z": 0.1,
    "l_ankle_z": 0.1,
    "r_ankle_z": 0.1,
}


#: σ (radians) of a prior towards the initial (clicked) posture for DOFs that hardly
#: move in a person and that the surface barely observes: without it, a per-frame
#: prior towards the prediction lets them wander over a long take.  The spine's twists
#: (z) get 0.3: in make demo's walk the pelvis turns ±20° under still shoulders and the
#: fit turns it too little (trunk twist error up to 18°; 16° with 0.3).  With 0.3:
#: MPJPE 12.23 → 10.93 mm (right ankle 20.7 → 8.8 mm), jumps_line3 20.48 → 20.33; with
#: 1.0 the demo's hidden arm lost its coupling (core.fit_coupling), 13.82 mm.
ANCHOR_SIGMA = {
    "l_clavicle_z": 0.05,
    "l_clavicle_y": 0.05,
    "r_clavicle_z": 0.05,
    "r_clavicle_y": 0.05,
    "lowerback_x": 0.1,
    "lowerback_y": 0.1,
    "lowerback_z": 0.3,
    "spine_x": 0.1,
    "spine_y": 0.1,
    "spine_z": 0.3,
    "chest_x": 0.1,
    "chest_y": 0.1,
    "chest_z": 0.3,
    "neck_x": 0.15,
    "neck_y": 0.15,
    "neck_z": 0.15,
    "head_x": 0.2,
    "head_y": 0.2,
    "l_ankle_z": 0.15,
    "r_ankle_z": 0.15,
}
