"""The SMPL-X backend, run for real on a synthetic file in the SMPL-X layout."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from fake_smplx import SMPLX_PARENTS, write_fake_smplx
from geometry import distance_to_mesh

from pghm.body import BodyPose, load_body
from pghm.body.smplx_backend import SMPLXBody
from pghm.errors import PghmError
from pghm.uv.atlas import build_atlas
from pghm.uv.maps import posed_points, texel_surface, uv_position_map


@pytest.fixture(scope="module")
def smplx_body(tmp_path_factory):
    path = write_fake_smplx(tmp_path_factory.mktemp("smplx") / "SMPLX_NEUTRAL.npz")
    return SMPLXBody(path)


def test_loads_the_smplx_layout(smplx_body):
    assert smplx_body.name == "smplx" and smplx_body.num_bones == 55
    assert smplx_body.parents == SMPLX_PARENTS
    assert smplx_body.bone_names[:3] == ["pelvis", "left_hip", "right_hip"]
    assert len(smplx_body.shape_names) == 10
    assert smplx_body.joint_map["left_elbow"] == 18


def test_betas_change_the_rest_shape(smplx_body):
    base = smplx_body.rest()
    shaped = smplx_body.rest(torch.ones(10))
    assert (shaped.vertices - base.vertices).abs().max() > 1e-3
    # Joints follow the regressor: the mean of their ring.
    torch.testing.assert_close(shaped.joints, smplx_body.j_regressor @ shaped.vertices)


def test_produces_the_same_kind_of_maps(smplx_body):
    atlas = build_atlas(smplx_body, 64, use_cache=False)
    assert atlas.num_texels > 1000 and atlas.overlap_count == 0
    rest = smplx_body.rest(dtype=torch.float64)
    surface = texel_surface(smplx_body, atlas, rest)
    # float32 barycentrics sum to one within 1e-7.
    assert distance_to_mesh(surface.positions, rest.vertices, smplx_body.faces).max() < 1e-6
    gen = torch.Generator().manual_seed(0)
    pose = BodyPose(
        torch.randn(1, 55, 3, generator=gen, dtype=torch.float64) * 0.4, torch.zeros(1, 3, dtype=torch.float64)
    )
    transforms = smplx_body.bone_transforms(pose, rest.joints)
    texels = posed_points(surface, transforms)
    vertices = smplx_body.posed_vertices(pose, rest)
    blended = (vertices[:, smplx_body.faces[atlas.face]] * atlas.barycentric.double()[None, :, :, None]).sum(2)
    assert (texels - blended).abs().max() < 1e-10
    assert uv_position_map(surface, atlas, transforms).shape == (1, 3, 64, 64)


def test_missing_or_broken_file_is_one_clear_error(tmp_path):
    with pytest.raises(PghmError, match="not found"):
        SMPLXBody(tmp_path / "nope.npz")
    broken = tmp_path / "broken.npz"
    np.savez(broken, f=np.zeros((1, 3)))
    with pytest.raises(PghmError, match="SMPL-X"):
        SMPLXBody(broken)
    with pytest.raises(PghmError, match="body-model-path"):
        load_body("smplx")
    with pytest.raises(PghmError, match="unknown body"):
        load_body("smpl-h")
