"""The shared joint vocabulary: names used by truth, clicks, the body model and metrics.

Every joint position the project exchanges (``truth.npz`` ``joint_names``,
``clicks.json`` joints, fitted-state joints) uses these names.  World frame: Z up,
metres.
"""

#: All named joints, in a fixed order.  ``pelvis`` is the root (mid-hips).
JOINTS = (
    "pelvis",
    "spine",
    "chest",
    "neck",
    "head",
    "head_top",
    "l_clavicle",
    "l_shoulder",
    "l_elbow",
    "l_wrist",
    "l_hand",
    "r_clavicle",
    "r_shoulder",
    "r_elbow",
    "r_wrist",
    "r_hand",
    "l_hip",
    "l_knee",
    "l_ankle",
    "l_toe",
    "r_hip",
    "r_knee",
    "r_ankle",
    "r_toe",
)

#: The documented landmark set over which MPJPE and the max error are computed.
METRIC_JOINTS = (
    "head",
    "neck",
    "l_shoulder",
    "r_shoulder",
    "l_elbow",
    "r_elbow",
    "l_wrist",
    "r_wrist",
    "l_hip",
    "r_hip",
    "l_knee",
    "r_knee",
    "l_ankle",
    "r_ankle",
)

#: Key joints a user clicks to initialise a fit (a subset of ``JOINTS``).
CLICK_JOINTS = METRIC_JOINTS + ("pelvis",)

#: Joints a user may click as well: the toes give each foot's direction, which no other
#: click fixes (the shin's own twist comes from the knee's bend).
OPTIONAL_CLICK_JOINTS = ("l_toe", "r_toe")

#: Segments whose orientation is scored: name -> (proximal joint, distal joint).
SEGMENTS = {
    "l_upper_arm": ("l_shoulder", "l_elbow"),
    "l_forearm": ("l_elbow", "l_wrist"),
    "r_upper_arm": ("r_shoulder", "r_elbow"),
    "r_forearm": ("r_elbow", "r_wrist"),
    "l_thigh": ("l_hip", "l_knee"),
    "l_shin": ("l_knee", "l_ankle"),
    "r_thigh": ("r_hip", "r_knee"),
    "r_shin": ("r_knee", "r_ankle"),
    "trunk": ("pelvis", "neck"),
    "head": ("neck", "head_top"),
}
