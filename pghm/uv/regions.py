"""Body regions on the UV map: which body part each texel of the L x L atlas belongs to.

The viewer's per-region latent gain scales the identity map F (1, C, L, L) by one factor
per region; this module gives the (L, L) label map those factors are scattered with.

A texel's region is the body part of its dominant bone (the largest of its skinning
weights, ``geometry.surface.weights``), through the synthetic-data engineer's
:func:`pghm.synth.regions.bone_parts` (bone -> nearest canonical ancestor -> part).
Limb parts (arms, hands, legs, feet) are split into the body's left (canonical x >= 0, the
side the body's left faces in the world frame of :mod:`pghm.body.pose`) and right copies.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from pghm.synth.regions import PART_NAMES, bone_parts

SIDED_PARTS = ("upper_arm", "lower_arm", "hand", "upper_leg", "lower_leg", "foot")
"""Parts that come as a left and a right region."""

REGION_NAMES: tuple[str, ...] = tuple(
    name for part in PART_NAMES for name in ((f"left_{part}", f"right_{part}") if part in SIDED_PARTS else (part,))
)
"""Regions in label order: head, neck, torso, hips, left_upper_arm, right_upper_arm, ..."""

NO_REGION = -1
"""Label of texels that carry no Gaussian (outside every UV island)."""


@dataclass(frozen=True)
class RegionMap:
    """Region labels of the texels of one atlas.

    Attributes:
        texel_labels: (N,) long region index of each valid texel, into ``names``.
        labels: (L, L) long region index per texel of the map, NO_REGION where no texel is.
        names: the region names, :data:`REGION_NAMES`.
    """

    texel_labels: Tensor
    labels: Tensor
    names: tuple[str, ...] = REGION_NAMES

    def gain_map(self, gains: Tensor) -> Tensor:
        """(1, 1, L, L) per-texel factor for per-region ``gains`` (R,); 1 where no texel is."""
        table = torch.cat([gains.to(torch.float32), torch.ones(1)])  # index NO_REGION = -1 -> the last entry
        return table[self.labels][None, None]


def texel_regions(
    weights: Tensor,
    positions: Tensor,
    bone_names: list[str],
    parents: list[int],
    joint_map: dict[str, int],
) -> Tensor:
    """(N,) long region index of N texels from their skinning weights (N, J) and canonical positions (N, 3)."""
    part_of_bone = torch.from_numpy(bone_parts(list(bone_names), list(parents), dict(joint_map)))
    part = part_of_bone[weights.argmax(dim=1)]  # part of the dominant bone
    left = positions[:, 0] >= 0
    region_of = {name: index for index, name in enumerate(REGION_NAMES)}
    labels = torch.empty_like(part)
    for index, name in enumerate(PART_NAMES):
        rows = part == index
        if name in SIDED_PARTS:
            labels[rows & left] = region_of[f"left_{name}"]
            labels[rows & ~left] = region_of[f"right_{name}"]
        else:
            labels[rows] = region_of[name]
    return labels


def region_map(geometry, body) -> RegionMap:
    """The :class:`RegionMap` of a :class:`~pghm.model.geometry.SubjectGeometry` on ``body``'s skeleton."""
    atlas = geometry.atlas
    texel_labels = texel_regions(
        geometry.surface.weights, geometry.surface.positions, body.bone_names, body.parents, body.joint_map
    )
    size = atlas.resolution
    labels = torch.full((size * size,), NO_REGION, dtype=torch.long)
    labels[atlas.flat_index] = texel_labels  # texel_rc scattered to the L x L map
    return RegionMap(texel_labels=texel_labels, labels=labels.view(size, size))


def region_counts(regions: RegionMap) -> np.ndarray:
    """(R,) number of texels (Gaussians) in each region."""
    return np.bincount(regions.texel_labels.numpy(), minlength=len(regions.names))
