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
12 synthetic identities of the generator (``pghm.synth``, all five motion kinds,
6 views in a ring, 8 poses each, 512 x 512, white background; 576 images), MediaPipe
``mediapipe==0.10.14`` ``solutions.pose.Pose(model_complexity=1, static_image_mode=True)``
on each image, detections with visibility > 0.5 kept. For each landmark, softmax weights
over the 48 rest vertices nearest to its anchor joint and the 48 nearest to the best single
vertex minimise the Huber (4 px) reprojection error against the true posed bodies over all
images; the 8 largest are kept and refitted; where the other side's combination, mirrored
across x = 0, explains a landmark better it replaces it (the right hip: 8.3 -> 5.7 px).
The residuals (median pixels, persons about 300 px tall) are in docs/capture.md (Body fit) and
``benchmarks/results/derive_landmarks.json``.
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
    0: (  # nose
        (281, 7034, 277, 278, 5037, 279, 198, 5240),
        (0.5689, 0.4267, 0.0012, 0.0009, 0.0009, 0.0007, 0.0004, 0.0002),
    ),
    2: (  # left_eye
        (7828, 13584, 13585, 7388, 7749, 7775, 7827, 7801),
        (0.3568, 0.2498, 0.1493, 0.1322, 0.0493, 0.0364, 0.0203, 0.0058),
    ),
    5: (  # right_eye
        (1099, 1152, 1073, 1151, 13657, 13656, 1125, 93),
        (0.6509, 0.3471, 0.0008, 0.0004, 0.0004, 0.0002, 0.0002, 0.0),
    ),
    7: (  # left_ear
        (11969, 7022, 685, 5350, 686, 7559, 7021, 11813),
        (0.4281, 0.2716, 0.1171, 0.0807, 0.0443, 0.0313, 0.0159, 0.011),
    ),
    8: (  # right_ear
        (5386, 269, 7396, 11936, 7397, 870, 268, 5220),
        (0.4281, 0.2716, 0.1171, 0.0807, 0.0443, 0.0313, 0.0159, 0.011),
    ),
    9: (  # mouth_left
        (7181, 7268, 677, 7190, 7164, 7253, 7180, 7177),
        (0.6589, 0.1243, 0.1037, 0.1015, 0.01, 0.001, 0.0004, 0.0002),
    ),
    10: (  # mouth_right
        (542, 558, 567, 5334, 550, 519, 559, 475),
        (0.9618, 0.0368, 0.0005, 0.0003, 0.0003, 0.0002, 0.0001, 0.0001),
    ),
    11: (  # left_shoulder
        (8072, 8332, 8281, 8257, 10393, 8337, 8330, 8326),
        (0.4505, 0.2071, 0.1511, 0.0935, 0.0788, 0.018, 0.0005, 0.0004),
    ),
    12: (  # right_shoulder
        (1481, 1653, 1670, 1676, 1625, 1681, 1674, 1397),
        (0.5172, 0.2066, 0.1916, 0.0568, 0.0276, 0.0001, 0.0001, 0.0),
    ),
    13: (  # left_elbow
        (10491, 10035, 10004, 10015, 10021, 9990, 9992, 9998),
        (0.3209, 0.281, 0.1401, 0.0895, 0.0823, 0.0645, 0.0178, 0.0038),
    ),
    14: (  # right_elbow
        (3842, 3383, 3352, 3363, 3369, 3338, 3340, 3346),
        (0.3209, 0.281, 0.1401, 0.0895, 0.0823, 0.0645, 0.0178, 0.0038),
    ),
    15: (  # left_wrist
        (10529, 10279, 10463, 10516, 10465, 10469, 10467, 10193),
        (0.4835, 0.3462, 0.1535, 0.0111, 0.0025, 0.0019, 0.001, 0.0003),
    ),
    16: (  # right_wrist
        (3880, 3627, 3813, 3867, 3815, 3819, 3817, 3541),
        (0.4835, 0.3462, 0.1535, 0.0111, 0.0025, 0.0019, 0.001, 0.0003),
    ),
    23: (  # left_hip
        (10905, 4346, 10827, 10835, 10913, 4354, 10836, 10843),
        (0.3449, 0.2761, 0.1895, 0.112, 0.0687, 0.0036, 0.003, 0.0021),
    ),
    24: (  # right_hip
        (4291, 10954, 4208, 4217, 4299, 4354, 4218, 4226),
        (0.3449, 0.2761, 0.1895, 0.112, 0.0687, 0.0036, 0.003, 0.0021),
    ),
    25: (  # left_knee
        (11182, 11224, 11200, 11262, 11243, 11202, 11278, 11198),
        (0.2973, 0.2204, 0.1724, 0.1642, 0.0584, 0.0438, 0.0411, 0.0024),
    ),
    26: (  # right_knee
        (4580, 4622, 4598, 4660, 4641, 4600, 4676, 4596),
        (0.2973, 0.2204, 0.1724, 0.1642, 0.0584, 0.0438, 0.0411, 0.0024),
    ),
    27: (  # left_ankle
        (12940, 12995, 12806, 12982, 12925, 12946, 12997, 12996),
        (0.2904, 0.259, 0.2083, 0.1781, 0.041, 0.0143, 0.0079, 0.0011),
    ),
    28: (  # right_ankle
        (6220, 6341, 6401, 6272, 6363, 4786, 6344, 4829),
        (0.2977, 0.2209, 0.2188, 0.1636, 0.0582, 0.0331, 0.0041, 0.0037),
    ),
    29: (  # left_heel
        (12788, 12922, 13018, 13022, 13019, 12881, 12878, 12783),
        (0.3986, 0.345, 0.1315, 0.0599, 0.0567, 0.0042, 0.0032, 0.0008),
    ),
    30: (  # right_heel
        (6438, 6341, 6439, 6308, 6442, 6355, 6207, 6300),
        (0.3041, 0.2411, 0.2129, 0.1518, 0.0638, 0.0161, 0.0065, 0.0037),
    ),
    31: (  # left_foot_index
        (12367, 11544, 12412, 11606, 11590, 11586, 11618, 11615),
        (0.6205, 0.3568, 0.019, 0.0017, 0.0008, 0.0007, 0.0003, 0.0002),
    ),
    32: (  # right_foot_index
        (4942, 6156, 4953, 6159, 6163, 4892, 6158, 6162),
        (0.759, 0.2388, 0.0009, 0.0006, 0.0003, 0.0002, 0.0002, 0.0001),
    ),
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
            name = LANDMARK_NAMES[landmark]
            raise ValueError(f"landmark {name} uses vertex {max(vertices)} of a {num_vertices}-vertex body")
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
