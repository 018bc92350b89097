"""``capture(input, out, config)``: a video (or a folder of images) becomes a subject folder.

    reader ──► pass 1: track the person on frames scaled to 512 px (boxes only)
           ──► crop: the region the person occupies over the video, intrinsics adjusted
           ──► pass 2: the cropped frames at the subject's size: mask, landmarks, matte, images written
           ──► body fit (pghm.capture.bodyfit): shape, per-frame pose, camera
           ──► cameras.npz, poses.npz, splits.json, meta.json (docs/data.md)

Both passes stream: ffmpeg decodes, crops and scales in C, Python holds one frame at a
time; the masks the body fit needs go to a memory-mapped file. The subject is built in a
hidden temporary folder beside ``out`` and renamed into place at the end: an error or a
Ctrl-C leaves nothing behind.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pghm.capture.config import BodyFitConfig, CaptureConfig
from pghm.capture.crop import (
    Region,
    crop_intrinsics,
    edge_pixels,
    frame_box,
    frame_edges,
    person_region,
    to_region,
)
from pghm.capture.frontend import (
    NUM_LANDMARKS,
    Observations,
    PersonInBox,
    Track,
    native_logs_silenced,
    track_person,
)
from pghm.capture.matte import colour_matte, on_white
from pghm.capture.video import ImageFolder, VideoFile, open_source, scaled_size
from pghm.errors import PghmError, listed
from pghm.io.outputs import check_output, staged_folder
from pghm.subject import SubjectArrays, write_image, write_subject

TRACKING_SIZE = 512
"""Longest side of the frames the person is tracked on (pass 1), pixels."""

MASKS_FILE = "masks.npy"
"""The memory-mapped (F, H, W) masks, in the temporary folder only."""

SHOWN_FRAMES = 12
"""Frame numbers listed in a message before "and N more"."""

WHITE = 255

CUT_EDGE_FRACTION = 0.02
"""A mask reaches past the frame on an edge when it covers more than this fraction of the image's
outermost row or column there: more than a fingertip (docs/lab/defaults.md, "Capture: a person
cut by the frame")."""
CUT_FRAMES_FRACTION = 0.25
"""The share of the kept frames with the person running out of the frame from which capture warns:
below it (a stride that reaches the edge now and then) most frames still show the whole body."""

POSE_NOISE = {"rotation_std_deg": 9.5, "translation_std_m": 0.05}
"""The error of a capture's poses, written to meta.json as the scale of ``pghm fit``'s prior on its
pose corrections (:func:`pghm.train.data.pose_noise`): the joints' measured rotation error over
bench_capture's videos, and the synthetic data's translation noise scaled alike
(docs/lab/defaults.md, "Capture: the poses' stated error")."""


def _warn(message: str) -> None:
    print(f"pghm: warning: {message}", file=sys.stderr)


def split_indices(count: int, test_every: int) -> tuple[list[int], list[int]]:
    """(train, test) image indices: images test_every - 1, 2 test_every - 1, ... are the test split."""
    test = [i for i in range(count) if (i + 1) % test_every == 0]
    return [i for i in range(count) if (i + 1) % test_every != 0], test


def _bar(config: CaptureConfig, total: int | None, stage: str) -> tqdm:
    return tqdm(total=total, desc=f"capture: {stage}", unit="frame", disable=not config.progress, file=sys.stderr)


def _require_frames(name: str, found: int, read: int, lost: list[int], config: CaptureConfig) -> None:
    """PghmError naming the file (and the frames lost) when fewer than ``config.min_frames`` are usable."""
    if read == 0:
        raise PghmError(f"{name}: no frame could be read")
    if found == 0:
        raise PghmError(f"{name}: no person found in any of the {read} frame(s) read")
    if found < config.min_frames:
        where = f" (not found in frames {listed(lost, SHOWN_FRAMES)})" if lost else ""
        raise PghmError(
            f"{name}: the person was found in {found} of {read} frame(s) read{where}; "
            f"capture needs at least {config.min_frames} (a longer video, or a smaller --every)"
        )


def _track(source: VideoFile | ImageFolder, config: CaptureConfig) -> Track:
    """Pass 1: the person's box in each frame, in pixels of the full upright frame."""
    full = Region.full(source.width, source.height)
    size = scaled_size(full, TRACKING_SIZE)
    total = source.frame_estimate and -(-source.frame_estimate // config.every)
    if config.max_frames is not None:
        total = min(total or config.max_frames, config.max_frames)
    frames = source.frames(full, size, config.every, config.max_frames)
    with _bar(config, total, "find person") as bar:
        track = track_person(frames, on_frame=bar.update)
    scale = np.array([source.width / size[1], source.height / size[0]] * 2)
    track.boxes = track.boxes * scale
    return track


def _observe(
    source: VideoFile | ImageFolder,
    track: Track,
    region: Region,
    out_size: tuple[int, int],
    K: np.ndarray | None,
    folder: Path,
    config: CaptureConfig,
) -> tuple[Observations, list[int]]:
    """Pass 2: masks and landmarks on the cropped frames; images and masks written to ``folder``.

    Returns the observations of the frames where the person was found again and the source
    frame numbers where not.
    """
    boxes = {int(i): box for i, box in zip(track.frame_index, track.boxes)}
    count = len(boxes)
    masks = np.lib.format.open_memmap(folder / MASKS_FILE, mode="w+", dtype=bool, shape=(count, *out_size))
    landmarks_2d = np.zeros((count, NUM_LANDMARKS, 2), np.float32)
    confidence = np.zeros((count, NUM_LANDMARKS), np.float32)
    landmarks_3d = np.zeros((count, NUM_LANDMARKS, 3), np.float32)
    kept, lost = [], []
    last = int(track.frame_index[-1])
    frames = source.frames(region, out_size, config.every, config.max_frames)
    with (
        PersonInBox(mirrored=config.mirror_pass) as measure,
        _bar(config, count, "masks, landmarks") as bar,
    ):
        for index, image in frames:
            if index in boxes:
                box = to_region(boxes[index].reshape(2, 2), region, out_size).reshape(4)
                found = measure(image, box)
                if found is None:
                    lost.append(index)
                else:
                    k = len(kept)
                    alpha, background = colour_matte(image, found.mask)
                    matte = np.round(alpha * WHITE).astype(np.uint8)  # the alpha stored is the one composited with
                    alpha = matte / np.float32(WHITE)
                    masks[k], landmarks_2d[k], confidence[k], landmarks_3d[k] = (
                        alpha >= 0.5,
                        found.landmarks_2d,
                        found.confidence,
                        found.landmarks_3d,
                    )
                    write_image(folder, k, on_white(image, alpha, background), matte)
                    kept.append(index)
                bar.update()
            if index >= last:
                break
    n = len(kept)
    observations = Observations(
        frame_index=np.array(kept, dtype=np.int32),
        image_size=out_size,
        K=None if K is None else K.astype(np.float32),
        landmarks_2d=landmarks_2d[:n],
        confidence=confidence[:n],
        landmarks_3d=landmarks_3d[:n],
        masks=masks[:n],
        frame_box=frame_box(region, source.width, source.height, out_size),
    )
    return observations, lost


@dataclass
class FrontEnd:
    """What the front end found in a video, before the body fit.

    Attributes:
        observations: the kept frames' masks and landmarks (masks memory-mapped in the folder).
        source_name: the input's file (or folder) name.
        source_size: (W, H) of its upright frames at full resolution.
        frames_read: frames read (after ``every`` and ``max_frames``).
        dropped: source frame numbers where the person was not found.
        region: the crop, pixels of the full upright frame.
        source_fps: the video's frame rate (None: a folder of images, or not stated).
        cut: source frame numbers of the kept frames whose person runs out of the frame.
        source_transfer: the video's HDR transfer function ("HLG", "PQ"), None for SDR; its frames
            were mapped to SDR when ``pghm.capture.video`` could.
        every: the stride the frames were read at.
    """

    observations: Observations
    source_name: str
    source_size: tuple[int, int]
    frames_read: int
    dropped: list[int]
    region: Region
    source_fps: float | None = None
    cut: list[int] = field(default_factory=list)
    source_transfer: str | None = None
    every: int = 1


def observe_video(
    input: str | os.PathLike, folder: Path, config: CaptureConfig, on_warning: Callable[[str], None] = _warn
) -> FrontEnd:
    """Passes 1 and 2: find and follow the person, crop, and write the subject's images and masks into ``folder``.

    Frames are read at ``config.stride`` of the video's length. Raises :class:`PghmError` for an
    unreadable input or too few frames with the person; warns once (``on_warning``) listing the
    frames dropped, and once when a long video is thinned.
    """
    source = open_source(input)
    config.check_camera(source.width, source.height)
    every = config.stride(source.frame_estimate)
    if config.every is None and every > 1:
        on_warning(
            f"{source.name}: about {source.frame_estimate} frames; reading one in {every}, about "
            f"{-(-source.frame_estimate // every)} (--every 1 reads them all, --target-frames sets how many)"
        )
    config = replace(config, every=every)
    if source.transfer and not source.tone_mapped:
        on_warning(
            f"{source.name}: an HDR ({source.transfer}) video, and this ffmpeg has no zscale filter to map it "
            "to SDR: the avatar's colours come out flat (convert it to SDR first, or record in SDR)"
        )
    with native_logs_silenced():
        track = _track(source, config)
        _require_frames(source.name, len(track.frame_index), track.frames_read, track.lost, config)
        region = person_region(track.boxes, source.width, source.height, config.crop_margin)
        config.check_crop_camera(region.width, region.height, source.width, source.height)
        out_size = scaled_size(region, config.size)
        K = config.source_intrinsics(source.width, source.height)
        K = None if K is None else crop_intrinsics(K, region, out_size)
        observations, lost_again = _observe(source, track, region, out_size, K, folder, config)
    dropped = sorted(track.lost + lost_again)
    _require_frames(source.name, len(observations.frame_index), track.frames_read, dropped, config)
    if dropped:
        on_warning(
            f"{source.name}: person not found in {len(dropped)} of {track.frames_read} frames "
            f"({listed(dropped, SHOWN_FRAMES)}); those frames are dropped"
        )
    # Each edge the frame ends at -> (F,) whether each kept frame's mask crosses it.
    crossed = {
        edge: edge_pixels(observations.masks, edge) > CUT_EDGE_FRACTION
        for edge in frame_edges(region, source.width, source.height)
    }
    cut = np.logical_or.reduce([*crossed.values(), np.zeros(len(observations.frame_index), bool)])
    cut_frames = observations.frame_index[cut].tolist()
    if cut.any() and cut.sum() >= CUT_FRAMES_FRACTION * len(cut):
        edges = ", ".join(edge for edge, flags in crossed.items() if flags.any())
        on_warning(
            f"{source.name}: the person runs out of the frame ({edges}) in {cut.sum()} of "
            f"{len(cut)} frames ({listed(cut_frames, SHOWN_FRAMES)}); "
            "the body there is guessed: film the whole body in view"
        )
    size = (source.width, source.height)
    return FrontEnd(
        observations,
        source.name,
        size,
        track.frames_read,
        dropped,
        region,
        source.fps,
        cut_frames,
        source.transfer,
        config.every,
    )


def capture(
    input: str | os.PathLike,
    out: str | os.PathLike,
    config: CaptureConfig | None = None,
    on_warning: Callable[[str], None] = _warn,
) -> Path:
    """Turn the video (or image folder) ``input`` into the new subject folder ``out``; return ``out``.

    Frames where the person is not found are dropped with one warning (``on_warning``)
    listing them. Raises :class:`PghmError` (one line naming the file and frames) for an
    unreadable or truncated video, no person, fewer than ``config.min_frames`` usable
    frames, or an ``out`` that exists and is not an empty folder; ``out`` is then not created.
    """
    config = (config or CaptureConfig()).validate()
    out = check_output(out, inputs=[input, config.polish], folder=True)
    if config.polish is not None:
        _check_polish_prior(config.polish)
    with staged_folder(out) as folder:
        front = observe_video(input, folder, config, on_warning)
        _write(folder, config, front)
        if config.polish is not None:
            from pghm.capture.polish import polish_poses

            polish_poses(folder, config.polish, progress=config.progress)
    return out


def _check_polish_prior(path: str) -> None:
    """Raise :class:`PghmError` unless ``path`` is a prior of the anny body: checked before the video is
    read, so that a wrong file fails in a second, not after the front end and the body fit."""
    from pghm.io.avatar import load_avatar

    prior = load_avatar(path)
    if prior.kind != "prior":
        raise PghmError(f"--polish {path}: a personalised avatar, not a prior (pghm train-prior's file)")
    if prior.body_name != "anny":
        raise PghmError(f"--polish {path}: a prior of the '{prior.body_name}' body; a capture fits anny")


def _write(folder: Path, config: CaptureConfig, front: FrontEnd) -> None:
    """Fit the body and write the subject's arrays and meta.json into ``folder`` (images are already there)."""
    import pghm
    from pghm.body import load_body
    from pghm.capture.bodyfit import fit_body

    observations = front.observations
    body_config = config.body or BodyFitConfig()
    if not config.pose_prior:
        body_config = replace(body_config, weight_motion_prior=0.0)
    if config.height_m is not None:
        body_config = replace(body_config, height_m=config.height_m)
    fit = fit_body(observations, body_config)
    n = len(observations.frame_index)
    train, test = split_indices(n, config.test_every)
    height, width = observations.image_size
    arrays = SubjectArrays(
        K=np.repeat(fit.K[None], n, axis=0),
        world_to_camera=np.repeat(fit.world_to_camera[None], n, axis=0),
        height=np.full(n, height),
        width=np.full(n, width),
        rotations=fit.rotations,
        translation=fit.translation,
        shape=fit.shape,
        body=body_config.body,
        bone_names=list(load_body(body_config.body).bone_names),
        splits={"train": train, "test": test},
        frame_index=observations.frame_index,
        view_index=np.zeros(n, dtype=np.int32),
    )
    (folder / MASKS_FILE).unlink()
    meta = {
        "source": "pghm capture",
        "input": front.source_name,
        "fps": front.source_fps,
        "hdr_transfer": front.source_transfer,
        "options": {**config.to_json(), "every": front.every},
        "pghm_version": pghm.__version__,
        "mediapipe_version": _version("mediapipe"),
        "counts": {
            "frames_read": front.frames_read,
            "person_found": front.frames_read - len(front.dropped),
            "dropped": len(front.dropped),
            "dropped_frames": front.dropped,
            "cut_frames": front.cut,
        },
        "crop": {"source_width": front.source_size[0], "source_height": front.source_size[1], **front.region.to_json()},
        "body_fit_residuals": {key: float(value) for key, value in fit.residuals.items()},
        "pose_noise": POSE_NOISE,
    }
    write_subject(folder, arrays, meta)


def _version(package: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(package)
    except PackageNotFoundError:
        return "unknown"
