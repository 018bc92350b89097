"""MediaPipe's pose landmarks as points on the Anny body: the measured correspondence.

MediaPipe Pose reports 33 landmarks (``mediapipe.solutions.pose.PoseLandmark`` numbering).
They are not Anny's joints: MediaPipe's hips sit higher and further apart than Anny's
``upperleg01`` heads, its shoulders on the top of the deltoid rather than at the
``upperarm01`` head, and its head landmarks are surface points (nose, eyes, ears). Each
body landmark l is therefore a fixed convex combination of a few rest vertices, carried
with the skinning,

    p_l = sum_k w_lk  LBS(v_{i_lk})            (w_lk >= 0, sum_k w_lk = 1),

so it follows the body's shape and pose (the vertices surround the point, so the
combination may lie inside the body, as a joint does).

How the constants were measured (``benchmarks/derive_landmarks.py`` re-derives them):
12 synthetic identities of the generator (``pghm.data.synth``, all five motion kinds,
6 views in a ring, 8 poses each, 512 x 512, white background; 576 images), MediaPipe
``mediapipe==0.10.14`` ``solutions.pose.Pose(model_complexity=1, static_image_mode=True)``
on each image, detections with visibility > 0.5 kept. For each landmark, softmax weights
over the 32 rest vertices nearest to its anchor joint and the 32 nearest to the best single
vertex minimise the Huber (4 px) reprojection error against the true posed bodies over all
images; the 6 largest are kept and refitted. The residuals (median pixels, persons about
300 px tall) are in docs/capture_body.md and ``benchmarks/results/derive_landmarks.json``.
"""

from __future__ import annotations

import torch
from torch import Tensor

LANDMARK_NAMES = (
    "nose",
    "left_eye_inner",
    "left_eye",
    "left_eye_outer",
    "right_eye_inner",
    "right_eye",
    "right_eye_outer",
    "left_ear",
    "right_ear",
    "mouth_left",
    "mouth_right",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_pinky",
    "right_pinky",
    "left_index",
    "right_index",
    "left_thumb",
    "right_thumb",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
    "left_heel",
    "right_heel",
    "left_foot_index",
    "right_foot_index",
)
"""MediaPipe's 33 pose landmarks in ``PoseLandmark`` order ("left" is the person's left,
as Anny's ``.L`` bones and the project's +x)."""

NUM_LANDMARKS = len(LANDMARK_NAMES)

LANDMARK_ANCHORS = {
    0: "head",
    2: "head",
    5: "head",
    7: "head",
    8: "head",
    9: "head",
    10: "head",
    11: "left_shoulder",
    12: "right_shoulder",
    13: "left_elbow",
    14: "right_elbow",
    15: "left_wrist",
    16: "right_wrist",
    23: "left_hip",
    24: "right_hip",
    25: "left_knee",
    26: "right_knee",
    27: "left_ankle",
    28: "right_ankle",
    29: "left_ankle",
    30: "right_ankle",
    31: "left_ankle",
    32: "right_ankle",
}
"""Body landmark (the ones the fit uses) -> the canonical joint (:data:`pghm.body.CANONICAL_JOINTS`)
it is attached to: its candidates' neighbourhood, and the baseline of the measurement. The
hand landmarks (17-22) and the inner/outer eye corners are left out: hands stay at rest,
and the eye corners add nothing to the eyes."""

BODY_LANDMARKS = tuple(LANDMARK_ANCHORS)
"""The landmark indices :func:`landmark_points` returns, in this order."""

LANDMARK_VERTICES: dict[int, tuple[tuple[int, ...], tuple[float, ...]]] = {
    0: ((198, 7045, 279, 294, 293, 5054), (0.715, 0.2793, 0.0031, 0.0013, 0.0009, 0.0005)),  # nose
    2: ((7775, 7828, 7749, 13585, 7827, 7801), (0.6513, 0.3473, 0.0007, 0.0003, 0.0003, 0.0002)),  # left_eye
    5: ((13657, 686, 1099, 1073, 1125, 1151), (0.4507, 0.1448, 0.137, 0.1327, 0.0779, 0.0569)),  # right_eye
    7: ((11813, 7559, 684, 685, 5350, 686), (0.6709, 0.0959, 0.0644, 0.0577, 0.0561, 0.0549)),  # left_ear
    8: ((5220, 5386, 7396, 11936, 7397, 870), (0.4681, 0.2355, 0.0956, 0.0822, 0.0686, 0.05)),  # right_ear
    9: ((7190, 686, 7253, 7177, 7180, 7268), (0.6993, 0.1026, 0.0873, 0.0484, 0.0431, 0.0193)),  # mouth_left
    10: ((542, 530, 519, 550, 5334, 536), (0.7641, 0.2345, 0.0004, 0.0003, 0.0003, 0.0003)),  # mouth_right
    11: ((8062, 10393, 8328, 8061, 8261, 8271), (0.3726, 0.209, 0.199, 0.106, 0.0857, 0.0277)),  # left_shoulder
    12: ((1672, 1454, 3741, 1397, 1671, 1482), (0.3566, 0.2679, 0.1731, 0.157, 0.0254, 0.0199)),  # right_shoulder
    13: ((10035, 10004, 9992, 10429, 9990, 10019), (0.3587, 0.1791, 0.1747, 0.1185, 0.1019, 0.0672)),  # left_elbow
    14: ((3387, 3298, 3400, 3370, 3336, 3401), (0.3881, 0.3723, 0.139, 0.0559, 0.0232, 0.0215)),  # right_elbow
    15: ((10516, 10315, 10465, 10193, 10468, 10467), (0.3411, 0.2915, 0.2392, 0.0831, 0.0289, 0.0162)),  # left_wrist
    16: ((3663, 3541, 3542, 3543, 3816, 3818), (0.5252, 0.3014, 0.0722, 0.0418, 0.036, 0.0236)),  # right_wrist
    23: ((4331, 10914, 10906, 10836, 10812, 10828), (0.2455, 0.2096, 0.1486, 0.1459, 0.1377, 0.1128)),  # left_hip
    24: ((4282, 4227, 4276, 4218, 4200, 4209), (0.4792, 0.4586, 0.0323, 0.0178, 0.0061, 0.006)),  # right_hip
    25: ((11182, 11242, 11243, 11200, 11261, 11202), (0.3917, 0.2448, 0.1713, 0.0848, 0.0746, 0.0329)),  # left_knee
    26: ((4580, 4660, 4598, 4622, 4641, 4603), (0.271, 0.2105, 0.182, 0.1416, 0.0995, 0.0953)),  # right_knee
    27: ((12944, 12806, 12997, 12925, 12994, 12946), (0.3676, 0.2144, 0.1272, 0.1059, 0.095, 0.09)),  # left_ankle
    28: ((6344, 6333, 6356, 4786, 4829, 6332), (0.3461, 0.3176, 0.1466, 0.1347, 0.035, 0.02)),  # right_ankle
    29: ((12936, 12788, 12909, 13018, 13022, 12881), (0.3292, 0.3152, 0.1751, 0.0873, 0.0485, 0.0446)),  # left_heel
    30: ((6442, 6311, 6333, 6336, 6300, 5851), (0.4838, 0.3088, 0.1584, 0.0266, 0.0187, 0.0037)),  # right_heel
    31: ((12367, 11544, 12412, 11615, 11606, 11622), (0.6215, 0.3567, 0.0172, 0.0018, 0.0015, 0.0011)),  # left_foot_index
    32: ((5004, 6158, 4942, 6160, 6162, 4953), (0.541, 0.378, 0.047, 0.0189, 0.0108, 0.0043)),  # right_foot_index
}
"""Body landmark -> (rest vertex indices, convex weights), measured (module docstring)."""


def landmark_regressor(num_vertices: int) -> tuple[Tensor, Tensor]:
    """The correspondence as gather indices and weights.

    Returns:
        indices: (L, K) long vertex indices of each body landmark (:data:`BODY_LANDMARKS`
            order), padded with vertex 0 at weight 0.
        weights: (L, K) convex weights.
    """
    width = max(len(v) for v, _ in LANDMARK_VERTICES.values())
    indices = torch.zeros(len(BODY_LANDMARKS), width, dtype=torch.long)
    weights = torch.zeros(len(BODY_LANDMARKS), width)
    for row, landmark in enumerate(BODY_LANDMARKS):
        vertices, w = LANDMARK_VERTICES[landmark]
        if max(vertices) >= num_vertices:
            raise ValueError(f"landmark {LANDMARK_NAMES[landmark]} uses vertex {max(vertices)} of a {num_vertices}-vertex body")
        indices[row, : len(vertices)] = torch.tensor(vertices)
        weights[row, : len(w)] = torch.tensor(w) / sum(w)
    return indices, weights


def landmark_points(vertices: Tensor) -> Tensor:
    """Body landmark positions from posed (or rest) vertices.

    Args:
        vertices: (B, V, 3) Anny vertices.

    Returns:
        points: (B, L, 3), L = len(BODY_LANDMARKS), in :data:`BODY_LANDMARKS` order.
    """
    indices, weights = landmark_regressor(vertices.shape[-2])
    gathered = vertices[:, indices.reshape(-1)].reshape(vertices.shape[0], *indices.shape, 3)
    return (weights.to(vertices.dtype)[None, ..., None] * gathered).sum(-2)
