"""A small synthetic model file in the SMPL-X layout, so the real SMPL-X loading code runs.

The mesh is an open tube along y (rings x segments) with a UV seam; the 55 joints of the
SMPL-X tree sit on its axis, each vertex skinned to the two joints nearest in height.
Only the layout is SMPL-X's; the geometry is not a body.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

SMPLX_PARENTS = [
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 15, 15, 15,
    20, 25, 26, 20, 28, 29, 20, 31, 32, 20, 34, 35, 20, 37, 38,
    21, 40, 41, 21, 43, 44, 21, 46, 47, 21, 49, 50, 21, 52, 53,
]  # fmt: skip
NUM_JOINTS = 55
NUM_SHAPE = 20  # 10 betas + 10 expression components, as in the first SMPL-X release


def write_fake_smplx(path: Path, rings: int = 24, segments: int = 16, seed: int = 0) -> Path:
    gen = np.random.default_rng(seed)
    heights = np.linspace(-0.9, 0.9, rings)
    angles = np.arange(segments + 1) / segments * 2 * np.pi  # the last column duplicates the first
    vertices, uv = [], []
    for y in heights:
        for a in angles[:-1]:
            vertices.append([0.15 * np.cos(a), y, 0.15 * np.sin(a)])
    for r in range(rings):
        for s in range(segments + 1):
            uv.append([0.05 + 0.9 * s / segments, 0.05 + 0.9 * r / (rings - 1)])
    vertices = np.array(vertices)
    faces, uv_faces = [], []
    for r in range(rings - 1):
        for s in range(segments):
            v00, v01 = r * segments + s, r * segments + (s + 1) % segments
            v10, v11 = v00 + segments, v01 + segments
            t00, t01 = r * (segments + 1) + s, r * (segments + 1) + s + 1
            t10, t11 = t00 + segments + 1, t01 + segments + 1
            faces += [[v00, v01, v11], [v00, v11, v10]]
            uv_faces += [[t00, t01, t11], [t00, t11, t10]]
    num_v = len(vertices)
    joint_heights = np.linspace(-0.85, 0.85, NUM_JOINTS)
    regressor = np.zeros((NUM_JOINTS, num_v))
    weights = np.zeros((num_v, NUM_JOINTS))
    for j, h in enumerate(joint_heights):
        ring = np.argmin(np.abs(heights - h))
        regressor[j, ring * segments : (ring + 1) * segments] = 1.0 / segments
    for v, p in enumerate(vertices):
        near = np.argsort(np.abs(joint_heights - p[1]))[:2]
        w = 1.0 / (np.abs(joint_heights[near] - p[1]) + 1e-3)
        weights[v, near] = w / w.sum()
    kintree = np.stack([np.array(SMPLX_PARENTS, dtype=np.int64), np.arange(NUM_JOINTS)])
    kintree[0, 0] = 4294967295  # the official files store the root's parent as uint32 -1
    np.savez(
        path,
        f=np.array(faces, dtype=np.uint32),
        ft=np.array(uv_faces, dtype=np.uint32),
        vt=np.array(uv, dtype=np.float64),
        v_template=vertices,
        shapedirs=gen.normal(scale=0.01, size=(num_v, 3, NUM_SHAPE)),
        posedirs=np.zeros((num_v, 3, (NUM_JOINTS - 1) * 9)),
        J_regressor=regressor,
        weights=weights,
        kintree_table=kintree,
        hands_componentsl=np.eye(45),
        hands_componentsr=np.eye(45),
        hands_meanl=np.zeros(45),
        hands_meanr=np.zeros(45),
        lmk_faces_idx=np.zeros(51, dtype=np.int64),
        lmk_bary_coords=np.full((51, 3), 1.0 / 3),
    )
    return path
