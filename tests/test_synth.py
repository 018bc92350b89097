"""The synthetic data generator: reproducibility, appearance, wrinkles, projection, poses.

Truth used here, independent of the renderer: camera projection written out in numpy
(:func:`project`), the project's own camera class (pghm.splat.camera) for the look-at
convention, and sample statistics for the injected pose noise.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import roma
import torch

from pghm.cli.main import main as cli_main
from pghm.errors import PghmError
from pghm.gl.context import headless_context
from pghm.subject import Subject, check
from pghm.synth import (
    SynthConfig,
    build_clothed_body,
    generate,
    load_config,
    plan_subject,
    pose_clothed_body,
    sample_identity,
)
from pghm.synth.cameras import intrinsics, look_at
from pghm.synth.cloth import WRINKLE_JOINTS, wrinkle_amplitudes
from pghm.synth.identity import ANNY_SHAPE_RANGES
from pghm.synth.poses import add_pose_noise
from pghm.synth.render import Lighting, MeshRenderer

BBOX_TOLERANCE_PX = 1
"""Silhouette vs projected-vertex bounding boxes: the mask keeps pixels at least half
covered, so a box edge can move by the partially covered pixel, never more."""

CLI_SEED = 5
"""Not 0, the default, so the run shows that ``--seed`` reaches the generator."""
CLI_SYNTH = ["synth", "--config", "tiny", "--seed", str(CLI_SEED), "--workers", "1", "--quiet"]

LIGHT = Lighting(direction=(0.36, 0.8, 0.48), colour=(0.9, 0.9, 0.9), ambient=0.4, shininess=32.0)


def _hash_tree(root: Path) -> dict[str, str]:
    return {
        str(path.relative_to(root)): hashlib.sha256(path.read_bytes()).hexdigest()
        for path in sorted(root.rglob("*"))
        if path.is_file()
    }


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("synth") / "tiny_seed0"
    generate(load_config("tiny"), seed=0, out=out, workers=1, progress=False)
    return out


@pytest.fixture(scope="module")
def gl():
    ctx = headless_context()
    yield ctx
    ctx.release()


def project(points: np.ndarray, K: np.ndarray, E: np.ndarray) -> np.ndarray:  # noqa: N803
    """(N, 2) pixel positions: t = R X + T, (u, v) = (fx tx / tz + cx, fy ty / tz + cy)."""
    cam = points @ E[:3, :3].T + E[:3, 3]
    return np.stack([K[0, 0] * cam[:, 0] / cam[:, 2] + K[0, 2], K[1, 1] * cam[:, 1] / cam[:, 2] + K[1, 2]], 1)


def pixel_bbox_of_points(uv: np.ndarray) -> tuple[int, int, int, int]:
    """Columns and rows whose pixel centres (j + 0.5, i + 0.5) fall inside the points' extent."""
    left, top = np.ceil(uv.min(0) - 0.5).astype(int)
    right, bottom = np.floor(uv.max(0) - 0.5).astype(int)
    return int(left), int(right), int(top), int(bottom)


def mask_bbox(mask: np.ndarray) -> tuple[int, int, int, int]:
    rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    return int(cols.min()), int(cols.max()), int(rows.min()), int(rows.max())


# ----------------------------------------------------------------- end to end


def test_tiny_dataset_is_valid_and_complete(tiny):
    assert check(tiny) == []
    meta = json.loads((tiny / "meta.json").read_text())
    assert meta["format"] == "pghm-dataset" and meta["seed"] == 0 and len(meta["subjects"]) == 2
    assert meta["config"]["width"] == 64 and meta["generator_version"]
    for name in meta["subjects"]:
        subject = Subject.open(tiny / name)
        assert len(subject) == 2 * 3  # 2 views x 3 frames
        assert subject.meta["identity"]["shape"] == pytest.approx(subject.arrays.shape.tolist(), abs=1e-6)
        frame = subject[0]
        assert frame.image.shape == (64, 64, 3) and frame.mask.shape == (64, 64)
        # The subject is in the picture; the mask is its alpha matte: pure white wherever the
        # matte is 0, partly covered pixels (0 < a < 1) on the outline only.
        assert 0.05 < (frame.mask >= 0.5).mean() < 0.6
        assert np.all(frame.image[frame.mask == 0] == 1.0)
        edge = (frame.mask > 0) & (frame.mask < 1)
        assert edge.any()
        # An image on white through matte a is a c + (1 - a) >= 1 - a (c >= 0): on black it is
        # I - (1 - a) >= 0 up to the 8-bit rounding of both files.
        assert (frame.image - (1 - frame.mask[..., None])).min() >= -1.0 / 255


def test_same_seed_gives_identical_bytes_and_other_seed_differs(tiny, tmp_path):
    generate(load_config("tiny"), seed=0, out=tmp_path / "again", workers=1, progress=False)
    generate(load_config("tiny"), seed=1, out=tmp_path / "other", workers=1, progress=False)
    first, again, other = _hash_tree(tiny), _hash_tree(tmp_path / "again"), _hash_tree(tmp_path / "other")
    assert first == again
    assert first.keys() == other.keys()
    differing = [name for name in first if first[name] != other[name]]
    images = [name for name in first if "/images/" in name]
    assert all(name in differing for name in images)


def test_worker_processes_write_the_same_bytes(tiny, tmp_path):
    generate(load_config("tiny"), seed=0, out=tmp_path / "pool", workers=2, progress=False)
    assert _hash_tree(tmp_path / "pool") == _hash_tree(tiny)


def test_cli_synth_then_check(tmp_path, capsys):
    out = tmp_path / "cli"
    assert cli_main(["synth", "--config", "tiny", "--seed", "3", "--out", str(out), "--workers", "1", "--quiet"]) == 0
    assert cli_main(["data", "check", str(out)]) == 0
    assert "ok (2 subject(s), 12 images)" in capsys.readouterr().out


def test_cli_synth_twice_writes_identical_bytes(tmp_path):
    """``pghm synth --config tiny --seed S --out DIR`` run twice gives files with equal
    SHA-256, meta.json included. One worker: a process pool costs seconds to start, and
    test_worker_processes_write_the_same_bytes shows that workers do not change the bytes."""
    runs = [tmp_path / "first", tmp_path / "second"]
    for out in runs:
        assert cli_main([*CLI_SYNTH, "--out", str(out)]) == 0
    first, second = (_hash_tree(out) for out in runs)
    assert any(name.endswith(".png") for name in first) and "meta.json" in first
    assert json.loads((runs[0] / "meta.json").read_text())["seed"] == CLI_SEED
    assert first == second


def test_generate_refuses_a_non_empty_folder(tmp_path):
    (tmp_path / "keep.txt").write_text("user data")
    with pytest.raises(PghmError, match="not empty"):
        generate(load_config("tiny"), seed=0, out=tmp_path, workers=1, progress=False)


# ----------------------------------------------------------------- config


def test_config_json_overrides_and_errors(tmp_path):
    path = tmp_path / "c.json"
    path.write_text(json.dumps({"identities": 3, "motions": ["walk", "squat"], "width": 96}))
    config = load_config(str(path))
    assert (config.identities, config.motions, config.width, config.height) == (3, ("walk", "squat"), 96, 256)
    path.write_text(json.dumps({"identitys": 3}))
    with pytest.raises(PghmError, match="unknown field"):
        load_config(str(path))
    path.write_text(json.dumps({"texture_size": 300}))
    with pytest.raises(PghmError, match="texture_size"):
        load_config(str(path))
    with pytest.raises(PghmError, match="neither a preset"):
        load_config("no-such-preset")


# ----------------------------------------------------------------- identities and textures


def test_identities_vary_and_stay_adult(body):
    identities = [sample_identity(np.random.default_rng(i), body.shape_names) for i in range(16)]
    assert len({ident.shirt.colour for ident in identities}) == 16
    assert len({ident.shirt.pattern for ident in identities}) >= 4
    assert len({ident.skin for ident in identities}) == 16
    for ident in identities:
        for name, value in zip(body.shape_names, ident.shape, strict=True):
            low, high = ANNY_SHAPE_RANGES[name]
            assert low <= value <= high


def test_textures_have_fine_detail_that_blur_destroys(body):
    """A 3x3 box blur of the albedo costs more than 3 dB below 35 dB PSNR: the painted
    detail (prints, hems, weave) lives at the texel scale."""
    ident = sample_identity(np.random.default_rng(5), body.shape_names)
    albedo = build_clothed_body(body, ident, 256).albedo[..., :3].astype(np.float64) / 255
    padded = np.pad(albedo, ((1, 1), (1, 1), (0, 0)), mode="edge")
    blurred = sum(padded[i : i + 256, j : j + 256] for i in range(3) for j in range(3)) / 9
    psnr = 10 * np.log10(1.0 / np.mean((albedo - blurred) ** 2))
    assert psnr < 32.0


# ----------------------------------------------------------------- wrinkles


def _bent_left_elbow(body, clothed, angle: float) -> np.ndarray:
    rotations = np.zeros((1, body.num_bones, 3))
    elbow, wrist = body.joint_map["left_elbow"], body.joint_map["left_wrist"]
    forearm = (clothed.joints[wrist] - clothed.joints[elbow]).numpy()
    axis = np.cross(forearm, [0.0, 0.0, 1.0])
    rotations[0, elbow] = angle * axis / np.linalg.norm(axis)
    return rotations


def test_wrinkles_follow_the_elbow_bend_and_leave_the_texture_alone(body, gl):
    ident = sample_identity(np.random.default_rng(3), body.shape_names)
    folded = build_clothed_body(body, ident, 256, wrinkles=True)
    plain = build_clothed_body(body, ident, 256, wrinkles=False)
    # The static texture does not depend on the folds.
    np.testing.assert_array_equal(folded.albedo, plain.albedo)
    assert np.abs(folded.wrinkles).max() > 0.3 and np.abs(plain.wrinkles).max() == 0

    straight, bent = np.zeros((1, body.num_bones, 3)), _bent_left_elbow(body, folded, 1.8)
    a_straight, a_bent = wrinkle_amplitudes(straight, body.joint_map), wrinkle_amplitudes(bent, body.joint_map)
    assert np.all(a_straight == 0)
    assert a_bent[0, WRINKLE_JOINTS.index("left_elbow")] > 0.9
    assert np.count_nonzero(a_bent) == 1

    elbow = folded.joints[body.joint_map["left_elbow"]].numpy()
    K = intrinsics(700.0, 160, 160)
    E = look_at(elbow + np.array([0.9, 0.1, 0.9]), elbow)
    renderer = MeshRenderer(gl, body.faces.numpy(), body.uv_faces.numpy(), body.uv_coords.numpy(), 160, 160)
    try:

        def draw(clothed, rotations, amplitudes, mode="lit", shader_amplitudes=None):
            renderer.set_textures(clothed.albedo, clothed.wrinkles)
            positions, normals = pose_clothed_body(body, clothed, rotations, np.zeros((1, 3)), amplitudes)
            renderer.set_geometry(positions[0], normals[0])
            shading = amplitudes[0] if shader_amplitudes is None else shader_amplitudes
            return renderer.render(K, E, LIGHT, shading, mode=mode).rgb.astype(int)

        # Straight elbow: folds have zero amplitude, the images are equal.
        np.testing.assert_array_equal(draw(folded, straight, a_straight), draw(plain, straight, a_straight))
        # Bent elbow: the folds change the shading of the elbow region.
        lit_folded, lit_plain = draw(folded, bent, a_bent), draw(plain, bent, a_bent)
        changed = np.abs(lit_folded - lit_plain).sum(-1) > 24
        assert changed.sum() > 150
        rows, cols = np.nonzero(changed)
        assert abs(np.median(rows) - 80) < 45 and abs(np.median(cols) - 80) < 45  # around the elbow
        # The same folded geometry drawn as the bare texture, with and without the folds'
        # shading: identical, the folds never touch the texture.
        no_folds = np.zeros(a_bent.shape[1])
        np.testing.assert_array_equal(
            draw(folded, bent, a_bent, mode="albedo"),
            draw(folded, bent, a_bent, mode="albedo", shader_amplitudes=no_folds),
        )
        assert np.abs(draw(folded, bent, a_bent) - draw(folded, bent, a_bent, shader_amplitudes=no_folds)).max() > 40
    finally:
        renderer.release()


# ----------------------------------------------------------------- projection


def test_rendered_mask_lines_up_with_projected_vertices(body, gl):
    """Off-centre principal point, non-square image, a posed body: the mask's bounding box
    equals the box of pixel centres inside the projected vertices' extent, within 1 px."""
    ident = sample_identity(np.random.default_rng(11), body.shape_names)
    clothed = build_clothed_body(body, ident, 128)
    rotations = np.zeros((1, body.num_bones, 3))
    rotations[0, body.joint_map["left_shoulder"]] = [0.0, 0.0, 1.2]
    rotations[0, body.joint_map["right_knee"]] = [0.9, 0.0, 0.0]
    rotations[0, 0] = [0.0, 0.7, 0.0]
    translation = np.array([[0.2, 0.05, -0.3]])
    amplitudes = wrinkle_amplitudes(rotations, body.joint_map)
    positions, normals = pose_clothed_body(body, clothed, rotations, translation, amplitudes)
    width, height = 120, 96
    K = intrinsics(70.0, width, height, principal_offset=(7.3, -4.6))
    renderer = MeshRenderer(gl, body.faces.numpy(), body.uv_faces.numpy(), body.uv_coords.numpy(), width, height)
    try:
        renderer.set_geometry(positions[0], normals[0])
        renderer.set_textures(clothed.albedo, clothed.wrinkles)
        for eye in ([0.5, 0.4, 3.0], [-2.6, 1.2, -1.1], [2.8, -0.3, 0.4]):
            E = look_at(np.array(eye), np.array([0.1, 0.0, -0.2]))
            mask = renderer.render(K, E, LIGHT).mask > 0
            expected = pixel_bbox_of_points(project(positions[0].astype(np.float64), K, E))
            assert np.abs(np.subtract(mask_bbox(mask), expected)).max() <= BBOX_TOLERANCE_PX
    finally:
        renderer.release()


def test_dataset_cameras_and_exact_poses_reproduce_the_masks(tiny, body):
    """What is on disk is consistent: re-posing the subject with rotations_true and
    projecting with the stored K and world_to_camera lands on the stored masks."""
    subject = Subject.open(tiny / "subject_001")
    plan = plan_subject(load_config("tiny"), body, 0, 1)
    clothed = build_clothed_body(body, plan.identity, 128)
    for index in (0, 3, 5):
        frame = subject[index]
        rotations = frame.rotations_true[None].astype(np.float64)
        translation = frame.translation_true[None].astype(np.float64)
        amplitudes = wrinkle_amplitudes(rotations, body.joint_map)
        positions, _ = pose_clothed_body(body, clothed, rotations, translation, amplitudes)
        uv = project(
            positions[0].astype(np.float64), frame.K.astype(np.float64), frame.world_to_camera.astype(np.float64)
        )
        expected = pixel_bbox_of_points(uv)
        assert np.abs(np.subtract(mask_bbox(frame.mask >= 0.5), expected)).max() <= BBOX_TOLERANCE_PX


def test_look_at_matches_the_splatter_camera():
    from pghm.splat.camera import Camera

    eye, target = np.array([1.3, 0.7, -2.9]), np.array([0.1, -0.2, 0.3])
    theirs = Camera.look_at(eye.tolist(), target.tolist()).world_to_camera.double().numpy()
    np.testing.assert_allclose(look_at(eye, target), theirs, atol=1e-6)


# ----------------------------------------------------------------- poses


def test_pose_noise_has_the_stated_level():
    rng = np.random.default_rng(0)
    frames, bones = 4000, 6
    true = np.zeros((frames, bones, 3))
    true[:, :, 1] = 0.6
    noisy, translation = add_pose_noise(true, np.zeros((frames, 3)), [1, 3], np.radians(2.0), 0.01, rng)
    error = roma.rotvec_composition(
        [torch.from_numpy(noisy[:, [1, 3]]), roma.rotvec_inverse(torch.from_numpy(true[:, [1, 3]]))]
    ).numpy()
    # The error rotation's vector is the injected N(0, 2 deg) sample: its std within 5 %
    # (4000 x 2 x 3 samples give a relative standard error of ~0.6 %).
    assert np.degrees(error.std()) == pytest.approx(2.0, rel=0.05)
    assert translation.std() == pytest.approx(0.01, rel=0.05)
    np.testing.assert_array_equal(noisy[:, [0, 2, 4, 5]], true[:, [0, 2, 4, 5]])


def test_stored_poses_are_noisy_and_exact_ones_are_kept(tiny):
    subject = Subject.open(tiny / "subject_000")
    a = subject.arrays
    difference = np.abs(a.rotations - a.rotations_true).max()
    assert 0 < difference < np.radians(15)
    assert np.abs(a.translation - a.translation_true).max() < 0.06
    # All views of a time step share one (noisy) pose, as a multi-view fit would.
    for frame in np.unique(a.frame_index):
        rows = np.flatnonzero(a.frame_index == frame)
        np.testing.assert_array_equal(a.rotations[rows[0]], a.rotations[rows[-1]])


def test_monocular_capture_holds_out_novel_poses_and_views(body, tmp_path):
    config = replace(
        SynthConfig(capture="monocular"),
        identities=1,
        frames=8,
        test_frames=4,
        novel_views=2,
        novel_view_stride=4,
        width=48,
        height=40,
        texture_size=64,
    )
    generate(config, seed=2, out=tmp_path / "mono", workers=1, progress=False)
    assert check(tmp_path / "mono") == []
    subject = Subject.open(tmp_path / "mono" / "subject_000")
    a = subject.arrays
    splits = a.splits
    assert splits["train"] == list(range(8))
    assert set(splits["test"]) == set(splits["test_novel_pose"]) | set(splits["test_novel_view"])
    assert np.all(a.view_index[splits["train"]] == 0) and np.all(a.view_index[splits["test_novel_view"]] > 0)
    assert np.all(a.frame_index[splits["test_novel_pose"]] >= 8)
    # Novel poses are not training poses: every test pose differs from every train pose.
    train = a.rotations_true[splits["train"]].reshape(len(splits["train"]), -1)
    for index in splits["test_novel_pose"]:
        assert np.abs(train - a.rotations_true[index].reshape(1, -1)).max(1).min() > 0.05
    # Novel views look from elsewhere: camera centres > 30 degrees around from the main one.
    centres = -np.einsum("nji,nj->ni", a.world_to_camera[:, :3, :3], a.world_to_camera[:, :3, 3])
    middle = a.translation_true[splits["train"]].mean(0)
    main_dir = centres[0] - middle
    for index in splits["test_novel_view"]:
        other = centres[index] - middle
        cosine = main_dir[[0, 2]] @ other[[0, 2]] / np.linalg.norm(main_dir[[0, 2]]) / np.linalg.norm(other[[0, 2]])
        assert cosine < np.cos(np.radians(30))


def test_monocular_motion_on_the_spot(body):
    """``mono_motion``: another motion kind instead of the walk, in place (the root moves only
    vertically), seen by the same panning camera; the walk travels; an unknown kind is refused."""
    from pghm.synth.video import walk_config

    squat = plan_subject(walk_config(12, 48, 40, 64, motion="squat"), body, 0, 0)
    walk = plan_subject(walk_config(12, 48, 40, 64), body, 0, 0)
    assert squat.motion_sources == ["procedural:squat"] and walk.motion_sources[0].endswith("walk")
    path = squat.arrays.translation_true[:, [0, 2]]
    assert np.abs(path).max() == 0 and np.ptp(squat.arrays.translation_true[:, 1]) > 0.05
    assert np.linalg.norm(walk.arrays.translation_true[-1, [0, 2]] - walk.arrays.translation_true[0, [0, 2]]) > 0.3
    with pytest.raises(PghmError, match="mono_motion"):
        walk_config(12, motion="cartwheel")
