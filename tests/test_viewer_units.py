"""The viewer's state without a window: identity edits, UV regions, orbit camera, pose and clock.

Each is checked against an independent construction: a bank built from known directions
and spreads for the PCA, rotation matrices for the slider composition, the camera's own
projection for panning, canonical joint positions for the regions.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import roma
import torch
from conftest import SMALL_MODEL as SMALL

from pghm.errors import PghmError
from pghm.model import ModelConfig, subject_geometry
from pghm.render import Framing
from pghm.uv.atlas import build_atlas
from pghm.uv.regions import NO_REGION, REGION_NAMES, region_counts, region_map
from viewer.camera import OrbitController
from viewer.demo import development_avatar
from viewer.identity import IdentityEditor, bank_pca
from viewer.scene import POSE_JOINTS, PoseState


@pytest.fixture(scope="module")
def geometry(body):
    return subject_geometry(body, build_atlas(body, SMALL.uv_resolution))


@pytest.fixture(scope="module")
def regions(body, geometry):
    return region_map(geometry, body)


# --------------------------------------------------------------------------- regions


def test_regions_label_exactly_the_valid_texels(geometry, regions):
    mask = geometry.atlas.mask
    assert ((regions.labels != NO_REGION) == mask).all()
    assert (region_counts(regions) > 0).all(), "every region has texels"
    assert region_counts(regions).sum() == geometry.num_gaussians


def test_regions_sit_on_their_body_parts(body, geometry, regions):
    """Head texels lie above the neck joint, left limbs at x > 0 beyond the shoulder/hip."""
    positions = geometry.surface.positions.numpy()
    joints = geometry.joints.numpy()
    label = regions.texel_labels.numpy()

    def of(name):
        return positions[label == REGION_NAMES.index(name)]

    neck = joints[body.joint_map["neck"]]
    assert (of("head")[:, 1] > neck[1] - 0.05).mean() > 0.99
    for side, sign in (("left", 1), ("right", -1)):
        wrist = joints[body.joint_map[f"{side}_wrist"]]
        assert (sign * of(f"{side}_hand")[:, 0] > sign * wrist[0] - 0.05).mean() > 0.95
        ankle = joints[body.joint_map[f"{side}_ankle"]]
        assert (of(f"{side}_foot")[:, 1] < ankle[1] + 0.1).mean() > 0.95
        assert (sign * of(f"{side}_upper_leg")[:, 0] > 0).all()


def test_gain_map_scales_each_region(regions):
    gains = torch.linspace(0.5, 2.0, len(REGION_NAMES))
    gain = regions.gain_map(gains)[0, 0]
    labels = regions.labels
    valid = labels != NO_REGION
    assert torch.equal(gain[valid], gains[labels[valid]])
    assert (gain[~valid] == 1).all()


# --------------------------------------------------------------------------- identity


def test_bank_pca_recovers_known_directions():
    """A bank mean + a_1 v_1 + a_2 v_2 with orthonormal v and known sample spreads."""
    rng = np.random.default_rng(0)
    shape = (4, 3, 3)
    size = int(np.prod(shape))
    directions = np.linalg.qr(rng.normal(size=(size, 2)))[0].T  # (2, D) orthonormal rows
    coefficients = np.stack([rng.normal(size=8) * 3.0, rng.normal(size=8) * 0.5], axis=1)
    coefficients -= coefficients.mean(axis=0)
    first, second = coefficients[:, 0], coefficients[:, 1]
    coefficients[:, 1] = second - first * (first @ second) / (first @ first)  # uncorrelated: PCA axes = v_1, v_2
    mean = rng.normal(size=size)
    bank = torch.from_numpy(mean + coefficients @ directions).reshape(8, *shape)
    pca = bank_pca(bank, max_components=6)
    assert len(pca.stds) == 2, "rank-2 bank: two components"
    np.testing.assert_allclose(pca.mean, mean, atol=1e-12)
    expected_stds = np.sqrt((coefficients**2).sum(axis=0) / 7)
    np.testing.assert_allclose(pca.stds, expected_stds, rtol=1e-10)
    for k in range(2):
        assert abs(abs(pca.components[k] @ directions[k]) - 1) < 1e-10


@pytest.fixture(scope="module")
def prior():
    torch.set_num_threads(2)
    return development_avatar(SMALL, kind="prior", num_identities=4, seed=5)


def test_blend_pca_and_gain_build_the_identity_map(prior, regions):
    editor = IdentityEditor(prior, regions)
    bank = prior.model.identity_bank.detach()
    with torch.no_grad():
        torch.testing.assert_close(editor.identity_map(), prior.model.decode_latent(bank[0:1]))
        editor.pick(2)
        editor.set_blend(3, 0.25)
        blended = 0.75 * bank[2] + 0.25 * bank[3]
        torch.testing.assert_close(editor.identity_map(), prior.model.decode_latent(blended[None]))
        editor.set_component(0, 1.5)
        step = torch.from_numpy(1.5 * editor.pca.stds[0] * editor.pca.components[0]).float().view_as(blended)
        expected = prior.model.decode_latent((blended + step)[None])
        torch.testing.assert_close(editor.identity_map(), expected, rtol=1e-5, atol=1e-6)
        editor.set_region_gain("head", 0.0)
        gained = editor.identity_map()
        head = regions.labels == REGION_NAMES.index("head")
        assert (gained[0][:, head] == 0).all()
        torch.testing.assert_close(gained[0][:, ~head], expected[0][:, ~head])
    first = editor.identity_map()
    assert editor.identity_map() is first, "an unchanged state reuses the map"
    editor.reset()
    assert editor.index_a == 0 and editor.blend == 0 and not editor.coefficients.any() and (editor.gains == 1).all()


def test_a_personal_avatar_has_no_bank_edits(regions):
    avatar = development_avatar(SMALL, seed=6)
    editor = IdentityEditor(avatar, regions)
    assert torch.equal(editor.identity_map(), avatar.latent)
    for action in (lambda: editor.pick(1), lambda: editor.set_blend(0, 0.5), lambda: editor.set_component(0, 1.0)):
        with pytest.raises(PghmError, match="needs a prior"):
            action()
    with pytest.raises(PghmError):
        editor.set_region_gain("head", 9.0)


# ----------------------------------------------------------------------------- camera


def project(camera, point) -> np.ndarray:
    w2c = camera.world_to_camera.double().numpy()
    t = w2c[:3, :3] @ np.asarray(point, float) + w2c[:3, 3]
    return np.array([camera.fx * t[0] / t[2] + camera.cx, camera.fy * t[1] / t[2] + camera.cy])


def test_orbit_pan_zoom_and_snaps():
    controller = OrbitController(home=Framing(target=(0.0, 0.1, 0.0), distance=3.0))
    controller.orbit(-225.0, 0.0)  # 0.4 degrees per pixel
    assert controller.yaw == pytest.approx(90.0)
    np.testing.assert_allclose(controller.camera(64, 48).centre.numpy(), [3.0, 0.1, 0.0], atol=1e-5)
    controller.orbit(0.0, 1e4)
    assert controller.pitch == 90.0, "pitch stops at the pole"
    controller.reset()
    before = controller.camera(400, 300)
    anchor = controller.target.copy()
    controller.pan(30.0, -20.0, 300)
    after = controller.camera(400, 300)
    # The point that was under the cursor follows it: the old target moves by the drag.
    np.testing.assert_allclose(project(after, anchor) - project(before, anchor), [30.0, -20.0], atol=1e-3)
    controller.zoom(2)
    assert controller.distance == pytest.approx(3.0 * 0.81)
    controller.snap("back")
    assert (controller.yaw, controller.pitch) == (180.0, 0.0)
    controller.snap("top")
    top = controller.camera(64, 48)
    np.testing.assert_allclose(top.world_to_camera[2, :3].numpy(), [0, -1, 0], atol=1e-6)
    with pytest.raises(PghmError):
        controller.set_fov(170.0)


# ------------------------------------------------------------------------------- pose


def test_sliders_compose_after_the_motion_rotation(body):
    from pghm.motion.open_motion import open_motion

    motion = open_motion("arm_raises", body)
    state = PoseState(motion=motion)
    state.time = 30 / motion.fps
    elbow = body.joint_map["left_elbow"]
    state.sliders[POSE_JOINTS.index("left_elbow")] = (0.0, 0.0, 90.0)
    pose = state.pose(body.joint_map)
    expected = roma.rotvec_to_rotmat(torch.from_numpy(motion.rotations[30, elbow]).double()) @ roma.rotvec_to_rotmat(
        torch.tensor([0.0, 0.0, math.pi / 2], dtype=torch.float64)
    )
    torch.testing.assert_close(roma.rotvec_to_rotmat(pose.rotations[0, elbow].double()), expected, atol=1e-5, rtol=0)
    untouched = [j for j in range(body.num_bones) if j != elbow]
    assert torch.equal(pose.rotations[0, untouched], torch.from_numpy(motion.rotations[30, untouched]))


def test_clock_loops_or_stops(body):
    from pghm.motion.open_motion import open_motion

    motion = open_motion("walk", body)  # 120 frames at 30 fps
    state = PoseState(motion=motion, playing=True)
    state.advance(4.5)
    assert state.frame == 15, "looped: 4.5 s = 135 frames = 15 past the end"
    state.loop, state.time = False, 0.0
    state.speed = 2.0
    state.advance(3.0)
    assert state.frame == 119 and not state.playing, "stopped on the last frame"
    state.advance(1.0)
    assert state.frame == 119


def test_driver_reuses_arrays_only_for_the_same_output_and_set():
    """Single-head models return one output for both sets: the set must still switch."""
    from pghm.render import AvatarDriver

    config = ModelConfig(**{**SMALL.to_dict(), "head": "single"})
    driver = AvatarDriver(development_avatar(config, seed=8))
    identity = driver.avatar.identity_map()
    centre = np.array([0.0, 0.0, 3.0])
    dynamic = driver.evaluate(identity, driver.rest_pose(), centre, "dynamic")
    assert driver.evaluate(identity, driver.rest_pose(), centre, "dynamic") is dynamic
    static = driver.evaluate(identity, driver.rest_pose(), centre, "static")
    assert static is not dynamic and not np.array_equal(static.colors, dynamic.colors)


def test_the_clip_list_offers_rest_the_procedural_and_the_shipped_clips(monkeypatch):
    from pghm.motion.procedural import PROCEDURAL_MOTIONS
    from viewer.scene import clip_choices, clip_index
    from viewer.settings import SHIPPED_MOTIONS

    choices = clip_choices()
    labels = [label for label, _ in choices]
    shipped = sorted(SHIPPED_MOTIONS.glob("*.bvh"))
    assert shipped, "the repository ships motion clips"
    assert labels == ["rest", *PROCEDURAL_MOTIONS, *(path.stem for path in shipped)]
    root = SHIPPED_MOTIONS.parent.parent
    monkeypatch.chdir(root)
    relative = shipped[0].relative_to(root)
    assert clip_index(choices, str(relative)) == labels.index(shipped[0].stem), "a relative path finds its clip"
    assert clip_index(choices, "squat") == labels.index("squat")
    assert clip_index(choices, "elsewhere/other.bvh") == -1


def test_an_interrupted_evaluation_keeps_its_finished_stages_and_resumes_to_the_same_gaussians(body):
    """Interrupt after the first stage (E_u / D_static); evaluating again finishes from there:
    E_u ran once in all, and the Gaussians equal an uninterrupted driver's."""
    from pghm.model.evaluator import Interrupted
    from pghm.motion.procedural import procedural_motion
    from pghm.render import AvatarDriver

    avatar = development_avatar(SMALL, seed=3)
    identity = avatar.identity_map()
    pose = procedural_motion("walk", body).pose(10)
    centre = np.array([0.4, 0.1, 2.5])
    driver = AvatarDriver(avatar)
    runs = driver.model.run_counts.copy()
    with pytest.raises(Interrupted):
        driver.evaluate(identity, pose, centre, interrupt=lambda: True)
    resumed = driver.evaluate(identity, pose, centre)
    assert (driver.model.run_counts - runs)["unet_encoder"] == 1, "the finished stage was kept"
    fresh = AvatarDriver(development_avatar(SMALL, seed=3)).evaluate(identity, pose, centre)
    for name in ("means", "scales", "colors", "opacities", "normals"):
        assert np.array_equal(getattr(resumed, name), getattr(fresh, name)), name
