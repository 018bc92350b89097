"""Fuzz the loaders of files users get from strangers: BVH clips, motion ``.npz``, ``avatar.pt``,
subject folders and the videos ``pghm capture`` reads.

    .venv/bin/python benchmarks/fuzz_loaders.py [--budget SECONDS] [--seed S] [--targets bvh,avatar,...]
                                                [--json OUT.json] [--crashes DIR]

The contract under test (pghm/errors.py): every problem with a file is one
:class:`~pghm.errors.PghmError`; any other exception escaping a loader is a bug. Each target
mutates valid seed inputs with a seeded random generator (structure-aware mutations — tokens
of a BVH, fields of an avatar payload, arrays of a motion file — and raw byte flips, cuts
and splices), runs the loader, and classifies the outcome:

    ok          the mutant loaded (and, for avatars and BVH clips, could be used: geometry
                built and one evaluation run / the clip retargeted onto the body)
    PghmError   rejected with one line (the subclass is counted)
    unexpected  any other exception: a finding; the input is saved to --crashes

Prints a table of cases tried and exceptions seen per target, and the distinct unexpected
exceptions with their reproducers. Exit status 1 when any unexpected exception was seen.
The time budget is split evenly between the targets; the same seed and budget give the same
mutants (not the same count: that depends on the machine's speed).
"""

from __future__ import annotations

import argparse
import copy
import io
import json
import logging
import math
import random
import subprocess
import sys
import tempfile
import time
import traceback
import warnings
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pghm.errors import PghmError  # noqa: E402

INTERESTING_NUMBERS = (
    "0",
    "-0",
    "1",
    "-1",
    "0.5",
    "1e308",
    "-1e308",
    "1e999",
    "-1e999",
    "5e-324",
    "1e-320",
    "nan",
    "-nan",
    "inf",
    "-inf",
    "99999999999999999999",
    "4294967296",
    "1_000",
    "0x10",
    "+",
    "-",
    ".",
    "1e",
    "e5",
    "\u0661",
    "\u00b2",
    "",
    "1,5",
    "1.5.5",
    "--1",
    "NaN",
    "Infinity",
)
"""Numbers (and near-numbers) that break parsers: extremes, denormals, non-finite spellings,
Python-only syntax (underscores, hex), Unicode digits."""

BVH_KEYWORDS = (
    "HIERARCHY",
    "ROOT",
    "JOINT",
    "End",
    "Site",
    "OFFSET",
    "CHANNELS",
    "{",
    "}",
    "MOTION",
    "Frames:",
    "Frame",
    "Time:",
    "Xrotation",
    "Yposition",
    "Zrotation",
)


# ------------------------------------------------------------------------------- seeds


def _joint(
    name: str, offset: tuple[float, float, float], children: list[str], indent: int, rotations: bool = True
) -> str:
    pad = "  " * indent
    lines = [f"{pad}JOINT {name}", f"{pad}{{", f"{pad}  OFFSET {offset[0]} {offset[1]} {offset[2]}"]
    if rotations:
        lines.append(f"{pad}  CHANNELS 3 Zrotation Xrotation Yrotation")
    lines += children or [f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET 0 5 0", f"{pad}  }}"]
    lines.append(f"{pad}}}")
    return "\n".join(lines)


def mixamo_clip(frames: int = 3) -> str:
    """A small Mixamo-named skeleton (every joint retargeting needs), ``frames`` frames, in cm."""

    def chain(names: list[tuple[str, tuple[float, float, float]]], indent: int) -> str:
        if not names:
            return ""
        (name, offset), rest = names[0], names[1:]
        inner = chain(rest, indent + 1)
        return _joint(name, offset, [inner] if inner else [], indent)

    legs = [
        chain([(f"{s}UpLeg", (x, -5, 0)), (f"{s}Leg", (0, -42, 0)), (f"{s}Foot", (0, -40, 0))], 1)
        for s, x in (("Left", 9.0), ("Right", -9.0))
    ]
    arms = [
        chain(
            [
                (f"{s}Shoulder", (x, 10, 0)),
                (f"{s}Arm", (x, 0, 0)),
                (f"{s}ForeArm", (2.2 * x, 0, 0)),
                (f"{s}Hand", (2 * x, 0, 0)),
            ],
            3,
        )
        for s, x in (("Left", 6.0), ("Right", -6.0))
    ]
    head = chain([("Neck", (0, 12, 0)), ("Head", (0, 10, 0))], 3)
    spine = _joint(
        "Spine", (0, 10, 0), [_joint("Spine1", (0, 10, 0), [_joint("Spine2", (0, 10, 0), [head, *arms], 2)], 1)], 1
    )
    joints = 1 + 6 + 8 + 2 + 3
    channels = 6 + 3 * (joints - 1)
    rows = []
    generator = random.Random(frames)
    for f in range(frames):
        values = [0.0, 95.0 + f, 2.0 * f, 0.0, 0.0, 0.0] + [generator.uniform(-30, 30) for _ in range(channels - 6)]
        rows.append(" ".join(f"{v:.3f}" for v in values))
    return "\n".join(
        [
            "HIERARCHY",
            "ROOT Hips",
            "{",
            "  OFFSET 0 95 0",
            "  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation",
            spine,
            *legs,
            "}",
            "MOTION",
            f"Frames: {frames}",
            "Frame Time: 0.0333333",
            *rows,
            "",
        ]
    )


SMALL_BVH = (ROOT / "tests" / "data" / "two_bone.bvh").read_text()


def write_small_subject(directory: Path, body) -> None:
    """A valid two-image, 8 x 8 pixel subject folder (the seed of the ``subject`` target)."""
    from pghm.subject import SubjectArrays, write_image, write_subject

    n = 2
    world_to_camera = np.repeat(np.eye(4)[None], n, 0)
    world_to_camera[:, 2, 3] = 3.0
    arrays = SubjectArrays(
        K=np.repeat(np.array([[8.0, 0, 4], [0, 8.0, 4], [0, 0, 1]])[None], n, 0),
        world_to_camera=world_to_camera,
        height=np.full(n, 8),
        width=np.full(n, 8),
        rotations=np.zeros((n, body.num_bones, 3)),
        translation=np.zeros((n, 3)),
        shape=np.full(6, 0.5),
        body="anny",
        bone_names=list(body.bone_names),
        splits={"train": [0, 1], "test": [1]},
    )
    for index in range(n):
        mask = np.zeros((8, 8), np.uint8)
        mask[2:6, 2:6] = 255
        write_image(directory, index, np.full((8, 8, 3), 200, np.uint8), mask)
    write_subject(directory, arrays, {"source": "fuzz"})


# --------------------------------------------------------------------------- mutators


def mutate_bytes(data: bytes, rng: random.Random) -> bytes:
    """Byte-level damage: flips, random insertions, cuts, duplicated spans, truncation."""
    raw = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        kind = rng.choice(("flip", "insert", "cut", "duplicate", "truncate"))
        position = rng.randrange(len(raw) + 1)
        if kind == "flip" and raw:
            raw[min(position, len(raw) - 1)] = rng.randrange(256)
        elif kind == "insert":
            raw[position:position] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 8)))
        elif kind == "cut":
            del raw[position : position + rng.randint(1, 64)]
        elif kind == "duplicate":
            raw[position:position] = raw[position : position + rng.randint(1, 256)]
        else:
            del raw[position:]
    return bytes(raw)


def mutate_bvh_text(text: str, rng: random.Random) -> str:
    """Token- and line-level mutations of a BVH file."""
    lines = text.split("\n")
    for _ in range(rng.randint(1, 3)):
        kind = rng.choice(
            (
                "number",
                "number",
                "keyword",
                "delete_line",
                "duplicate_line",
                "swap_lines",
                "frames",
                "frame_time",
                "channels",
                "append_rows",
            )
        )
        index = rng.randrange(len(lines)) if lines else 0
        if kind in ("number", "keyword") and lines:
            tokens = lines[index].split(" ")
            position = rng.randrange(len(tokens))
            tokens[position] = rng.choice(INTERESTING_NUMBERS if kind == "number" else BVH_KEYWORDS)
            lines[index] = " ".join(tokens)
        elif kind == "delete_line" and lines:
            del lines[index]
        elif kind == "duplicate_line" and lines:
            lines.insert(index, lines[index])
        elif kind == "swap_lines" and len(lines) > 1:
            other = rng.randrange(len(lines))
            lines[index], lines[other] = lines[other], lines[index]
        elif kind == "frames":
            value = rng.choice(("0", "1", "2", "3", "4", "100001", str(10**6), "-1", "1.5", "nan", ""))
            lines = [f"Frames: {value}" if line.startswith("Frames") else line for line in lines]
        elif kind == "frame_time":
            value = rng.choice(INTERESTING_NUMBERS)
            lines = [f"Frame Time: {value}" if line.startswith("Frame Time") else line for line in lines]
        elif kind == "channels":
            value = rng.choice(("0", "1", "2", "4", "7", "-3", "x", "99999999999999999999"))
            lines = [
                line.replace("CHANNELS 3", f"CHANNELS {value}", 1) if rng.random() < 0.3 else line for line in lines
            ]
        elif kind == "append_rows" and lines:
            row = next((line for line in reversed(lines) if line.strip()), "")
            lines += [row] * rng.randint(1, 3)
    return "\n".join(lines)


def random_value(rng: random.Random, like: object = None) -> object:
    """A value of a random kind, sometimes shaped like ``like`` but broken (NaN, wrong dtype, wrong shape)."""
    tensor = like if isinstance(like, torch.Tensor) else None
    choices = ["none", "int", "float", "string", "list", "dict", "tensor", "big_int", "nan", "bool"]
    if tensor is not None:
        choices += ["same_nan", "same_dtype", "same_shape", "same_shape", "empty", "scalar"]
    kind = rng.choice(choices)
    if kind == "none":
        return None
    if kind == "int":
        return rng.choice((0, -1, 1, 2, 3, 16, 32, 64, 1024))
    if kind == "big_int":
        return rng.choice((2**31, 2**63 - 1, -(2**63), 10**30))
    if kind == "float":
        return rng.choice((0.0, -1.0, 0.5, 1e308, float("inf"), 5e-324))
    if kind == "nan":
        return float("nan")
    if kind == "bool":
        return rng.choice((True, False))
    if kind == "string":
        return rng.choice(("", "avatar", "prior", "pghm-avatar", "anny", "smplx", "x" * 1000, "\x00"))
    if kind == "list":
        return rng.choice(([], [1], [1, 2, 3], ["a"], [None], [[1]]))
    if kind == "dict":
        return rng.choice(({}, {"a": 1}, {"name": "anny"}))
    if kind == "tensor":
        shape = tuple(rng.randint(0, 3) for _ in range(rng.randint(0, 4)))
        return torch.zeros(shape, dtype=rng.choice((torch.float32, torch.float64, torch.int64, torch.bool)))
    if kind == "same_nan":
        broken = tensor.clone().float()
        if broken.numel():
            broken.view(-1)[rng.randrange(broken.numel())] = rng.choice((float("nan"), float("inf")))
        return broken
    if kind == "same_dtype":
        return tensor.to(
            rng.choice((torch.float16, torch.bfloat16, torch.int64, torch.bool, torch.complex64, torch.uint8))
        )
    if kind == "same_shape":
        shape = list(tensor.shape) or [1]
        axis = rng.randrange(len(shape))
        shape[axis] = rng.choice((0, 1, shape[axis] + 1, max(shape[axis] - 1, 0), shape[axis] * 2))
        return torch.zeros(shape, dtype=tensor.dtype if tensor.is_floating_point() else torch.float32)
    if kind == "empty":
        return torch.zeros(0)
    return torch.tensor(rng.choice((0.0, 1.0, float("nan"))))


CONFIG_VALUES = {
    "uv_resolution": (16, 31, 32, 64, 2**20, "32", True, None, 2.0**5),
    "latent_channels": (0, -1, 5, 10**9, "4", None),
    "encoder_channels": ([4, 6], [4, 6, 8, 10], [], ["a", 6, 8], [10**9, 6, 8], [0, 6, 8], [-4, 6, 8], "468"),
    "decoder_channels": ([6], [6, 4, 2], [], [10**9, 4], "64"),
    "condition_channels": ([2, 2], [2, 2, 4, 4], [], [10**9, 2, 4]),
    "head": ("single", "multi", "x", None, 1),
    "max_static_offset": (float("nan"), float("inf"), -1.0, 1e308, "0.1"),
    "scale_factor_range": (0.0, -1.0, 1.0, float("nan"), 1e308),
    "min_scale": (0.0, -1.0, float("nan"), 1.0),
    "max_scale": (0.0, -1.0, float("inf"), 1e-9),
    "base_scale_factor": (0.0, -1.0, float("nan")),
}
"""Config fields and values that are wrong (or barely right) for them."""


def mutate_payload(payload: dict, rng: random.Random) -> dict:
    """One to three structural edits of an avatar payload: drop, replace or rename a field anywhere."""
    payload = copy.deepcopy(payload)
    for _ in range(rng.randint(1, 3)):
        kind = rng.choice(("top", "config", "config", "body", "weights", "weights", "metadata", "rename_weight"))
        if kind == "top":
            key = rng.choice(list(payload) + ["extra"])
            if key in payload and rng.random() < 0.3:
                del payload[key]
            else:
                payload[key] = random_value(rng, payload.get(key))
        elif kind == "config" and isinstance(payload.get("config"), dict):
            key = rng.choice(list(CONFIG_VALUES) + ["unknown_field"])
            if rng.random() < 0.15:
                payload["config"].pop(key, None)
            else:
                payload["config"][key] = rng.choice(CONFIG_VALUES.get(key, (1,)))
        elif kind == "body" and isinstance(payload.get("body"), dict):
            key = rng.choice(("name", "shape", "shapes"))
            if rng.random() < 0.2:
                payload["body"].pop(key, None)
            else:
                payload["body"][key] = random_value(rng, payload["body"].get(key))
        elif kind in ("weights", "rename_weight") and isinstance(payload.get("weights"), dict) and payload["weights"]:
            key = rng.choice(sorted(payload["weights"]))
            if kind == "rename_weight":
                payload["weights"][key + "_renamed"] = payload["weights"].pop(key)
            elif rng.random() < 0.15:
                del payload["weights"][key]
            else:
                payload["weights"][key] = random_value(rng, payload["weights"][key])
        elif kind == "metadata":
            payload["metadata"] = random_value(rng, None)
    return payload


def mutate_arrays(arrays: dict[str, np.ndarray], rng: random.Random) -> dict[str, np.ndarray]:
    """Edits of a motion file's arrays: drop or rename a key, change a dtype, shape or value."""
    arrays = dict(arrays)
    for _ in range(rng.randint(1, 3)):
        key = rng.choice(sorted(arrays) + ["extra"])
        kind = rng.choice(("drop", "rename", "dtype", "shape", "value", "scalar", "string"))
        value = arrays.get(key, np.zeros(1))
        if kind == "drop":
            arrays.pop(key, None)
        elif kind == "rename" and key in arrays:
            arrays[key + "x"] = arrays.pop(key)
        elif kind == "dtype":
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    arrays[key] = np.asarray(value).astype(
                        rng.choice((np.int8, np.float16, np.complex64, np.bool_, np.uint64, "U3"))
                    )
                except (ValueError, TypeError):  # a string that is not a number: keep the original
                    pass
        elif kind == "shape":
            flat = np.asarray(value).reshape(-1)
            arrays[key] = flat[: rng.randint(0, max(flat.size, 1))] if rng.random() < 0.5 else np.stack([value, value])
        elif kind == "value" and np.asarray(value).dtype.kind == "f" and np.asarray(value).size:
            changed = np.array(value, copy=True)
            changed.reshape(-1)[rng.randrange(changed.size)] = rng.choice((np.nan, np.inf, -np.inf, 1e38, -0.0))
            arrays[key] = changed
        elif kind == "scalar":
            arrays[key] = np.asarray(rng.choice((0.0, -1.0, np.nan, 1e-300, 1e300, 0, 30)))
        elif kind == "string":
            arrays[key] = np.asarray(rng.choice(("", "anny", "smplx", "x" * 100)))
    return arrays


# ---------------------------------------------------------------------------- targets


@dataclass
class TargetStats:
    """What one target saw."""

    name: str
    cases: int = 0
    ok: int = 0
    rejected: Counter = field(default_factory=Counter)
    unexpected: Counter = field(default_factory=Counter)
    seconds: float = 0.0
    examples: dict = field(default_factory=dict)
    """exception signature -> (reproducer path, one line of the message)."""


class Targets:
    """The loaders under test, each a function of a random generator that builds a mutant and loads it."""

    def __init__(self, workdir: Path) -> None:
        from pghm.body import load_body
        from pghm.io.avatar import Avatar, avatar_payload, save_avatar
        from pghm.model import PGHM, ModelConfig
        from pghm.motion.motion import Motion

        self.workdir = workdir
        self.body = load_body()
        self.bvh_seeds = [SMALL_BVH, mixamo_clip(3)]
        torch.manual_seed(0)
        config = ModelConfig(
            uv_resolution=32,
            latent_channels=4,
            encoder_channels=(4, 6, 8),
            decoder_channels=(6, 4),
            condition_channels=(2, 2, 4),
        )
        avatars = [
            Avatar(
                PGHM(config, 0),
                "avatar",
                "anny",
                torch.full((6,), 0.5),
                latent=torch.randn(1, 4, 32, 32),
                metadata={"steps": 1},
            ),
            Avatar(PGHM(config, 2), "prior", "anny", torch.full((6,), 0.5), shapes=torch.rand(2, 6)),
        ]
        self.payloads = [avatar_payload(avatar) for avatar in avatars]
        self.avatar_bytes = []
        for index, avatar in enumerate(avatars):
            path = workdir / f"seed{index}.pt"
            save_avatar(path, avatar)
            self.avatar_bytes.append(path.read_bytes())
        rest = np.zeros((4, self.body.num_bones, 3), np.float32)
        motion = Motion(rest + 0.1, np.zeros((4, 3), np.float32), 30.0, "anny", list(self.body.bone_names), "fuzz")
        motion.save(workdir / "seed.npz")
        self.motion_bytes = (workdir / "seed.npz").read_bytes()
        with np.load(workdir / "seed.npz", allow_pickle=False) as data:
            self.motion_arrays = {key: data[key] for key in data.files}
        self.subject_dir = workdir / "subject"
        write_small_subject(self.subject_dir, self.body)
        self.video_bytes = [seed_video(workdir / f"seed{k}{suffix}", options) for k, (suffix, options) in VIDEO_SEEDS]

    def bvh(self, rng: random.Random) -> bytes:
        """parse_bvh on mutated text (or bytes) of a seed clip."""
        from pghm.motion.bvh import parse_bvh

        seed = rng.choice(self.bvh_seeds)
        data = mutate_bvh_text(seed, rng).encode() if rng.random() < 0.8 else mutate_bytes(seed.encode(), rng)
        self._last = data
        parse_bvh(data, "fuzz.bvh")
        return data

    def bvh_import(self, rng: random.Random) -> bytes:
        """The whole import: a mutated Mixamo clip from disk, parsed and retargeted onto the body."""
        from pghm.motion.open_motion import open_motion

        data = mutate_bvh_text(self.bvh_seeds[1], rng).encode()
        self._last = data
        path = self.workdir / "case.bvh"
        path.write_bytes(data)
        motion = open_motion(path, self.body)
        assert np.isfinite(motion.rotations).all() and np.isfinite(motion.translation).all()
        return data

    def avatar(self, rng: random.Random) -> bytes:
        """load_avatar on a mutated payload (70 %) or damaged bytes (30 %); a file that loads is used."""
        from pghm.io.avatar import avatar_geometry, load_avatar
        from pghm.model.evaluator import CachedEvaluator

        if rng.random() < 0.7:
            buffer = io.BytesIO()
            torch.save(mutate_payload(rng.choice(self.payloads), rng), buffer)
            data = buffer.getvalue()
        else:
            data = mutate_bytes(rng.choice(self.avatar_bytes), rng)
        self._last = data
        path = self.workdir / "case.pt"
        path.write_bytes(data)
        avatar = load_avatar(path)
        geometry = avatar_geometry(avatar)
        evaluator = CachedEvaluator(avatar.model, geometry)
        from pghm.body import BodyPose

        out = evaluator.evaluate(
            avatar.identity_map(0), BodyPose.rest(self.body.num_bones), torch.tensor([0.0, 1.0, 3.0])
        )
        assert all(bool(torch.isfinite(t).all()) for t in (out.dynamic.means, out.dynamic.scales, out.dynamic.colors))
        return data

    def motion_npz(self, rng: random.Random) -> bytes:
        """Motion.load on mutated arrays (70 %) or damaged bytes (30 %)."""
        from pghm.motion.motion import Motion

        if rng.random() < 0.7:
            buffer = io.BytesIO()
            np.savez(buffer, **mutate_arrays(self.motion_arrays, rng))
            data = buffer.getvalue()
        else:
            data = mutate_bytes(self.motion_bytes, rng)
        self._last = data
        path = self.workdir / "case.npz"
        path.write_bytes(data)
        motion = Motion.load(path)
        motion.check_skeleton("anny", self.body.bone_names)
        motion.pose(0)
        return data

    def subject(self, rng: random.Random) -> bytes:
        """A subject folder with one damaged file: the checker lists problems, the reader and
        the training data raise one DatasetError or work."""
        import shutil

        from pghm.subject import Subject, check
        from pghm.train.data import TrainingData

        folder = self.workdir / "case_subject"
        shutil.rmtree(folder, ignore_errors=True)
        shutil.copytree(self.subject_dir, folder)
        name = rng.choice(
            ("cameras.npz", "poses.npz", "splits.json", "meta.json", "images/000001.png", "masks/000000.png")
        )
        path = folder / name
        if name.endswith(".npz") and rng.random() < 0.7:
            with np.load(path, allow_pickle=False) as data:
                arrays = {key: data[key] for key in data.files}
            buffer = io.BytesIO()
            np.savez(buffer, **mutate_arrays(arrays, rng))
            data = buffer.getvalue()
        elif name.endswith(".json") and rng.random() < 0.7:
            value = json.loads(path.read_text())
            key = rng.choice(sorted(value) + ["extra"]) if isinstance(value, dict) else None
            value[key] = random_value(rng) if key is not None else None
            data = json.dumps(value, default=lambda o: None).encode()
        else:
            data = mutate_bytes(path.read_bytes(), rng)
        path.write_bytes(data)
        self._last = name.encode() + b"\n" + data
        problems = check(folder)
        assert isinstance(problems, list)
        subject = Subject.open(folder)
        for index in range(len(subject)):
            subject[index]
        TrainingData(folder)
        return data

    def video(self, rng: random.Random) -> bytes:
        """A damaged video file (plain, 10-bit HDR, interlaced, non-square pixels) probed and read
        through every filter ``pghm capture`` uses: a crop at odd offsets, scaled down."""
        from pghm.capture.crop import Region
        from pghm.capture.video import open_source, scaled_size

        data = mutate_bytes(rng.choice(self.video_bytes), rng)
        self._last = data
        path = self.workdir / "case.mov"
        path.write_bytes(data)
        source = open_source(path)
        region = Region(1, 1, max(1, source.width - 2), max(1, source.height - 3))
        for _, image in source.frames(region, scaled_size(region, VIDEO_SIZE // 2), rng.choice((1, 2))):
            assert image.dtype == np.uint8 and image.ndim == 3
        return data


VIDEO_SIZE = 64
"""Longest side of the seed videos, pixels: small, so a case costs two ffmpeg runs of a few ms."""
VIDEO_SEEDS = tuple(
    enumerate(
        (
            (".mp4", ("-c:v", "libx264", "-pix_fmt", "yuv420p")),
            (".mov", ("-c:v", "libx265", "-pix_fmt", "yuv420p10le", "-color_trc", "arib-std-b67",
                      "-color_primaries", "bt2020", "-colorspace", "bt2020nc", "-x265-params", "log-level=error")),
            (".mp4", ("-c:v", "libx264", "-pix_fmt", "yuv420p", "-flags", "+ildct+ilme", "-x264-params", "tff=1")),
            (".mkv", ("-c:v", "libx264", "-pix_fmt", "yuv420p", "-vf", "setsar=2")),
        )
    )
)  # fmt: skip
"""What phones and cameras record, each one seed: 8-bit H.264, 10-bit HLG HEVC, interlaced, anamorphic."""


def seed_video(path: Path, options: tuple[str, ...]) -> bytes:
    """A short moving test pattern encoded with ffmpeg ``options``; its bytes."""
    import imageio_ffmpeg

    source = f"testsrc2=size={VIDEO_SIZE}x{VIDEO_SIZE * 3 // 4}:rate=10:duration=0.6"
    command = [imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-y", "-f", "lavfi", "-i", source, *options, str(path)]
    subprocess.run(command, check=True)
    return path.read_bytes()


TARGETS = ("bvh", "bvh_import", "avatar", "motion_npz", "subject", "video")
SUFFIX = {
    "bvh": ".bvh",
    "bvh_import": ".bvh",
    "avatar": ".pt",
    "motion_npz": ".npz",
    "subject": ".case",
    "video": ".mov",
}


def run_target(targets: Targets, name: str, seconds: float, seed: int, crashes: Path | None) -> TargetStats:
    """Run one target for ``seconds``; every case is one mutant from a generator seeded by (seed, case)."""
    stats = TargetStats(name)
    function: Callable[[random.Random], bytes] = getattr(targets, name)
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        rng = random.Random(f"{seed}:{name}:{stats.cases}")
        stats.cases += 1
        targets._last = b""
        try:
            function(rng)
            stats.ok += 1
        except PghmError as error:
            stats.rejected[type(error).__name__] += 1
            if "\n" in str(error):
                _record(stats, "PghmError spanning several lines", str(error), targets._last, name, crashes)
        except Exception as error:  # noqa: BLE001 - classifying every exception is the point
            frame = traceback.extract_tb(error.__traceback__)[-1]
            signature = f"{type(error).__name__} at {Path(frame.filename).name}:{frame.lineno}"
            _record(stats, signature, str(error), targets._last, name, crashes)
    stats.seconds = time.perf_counter() - start
    return stats


def _record(stats: TargetStats, signature: str, message: str, data: bytes, name: str, crashes: Path | None) -> None:
    stats.unexpected[signature] += 1
    if signature in stats.examples:
        return
    path = None
    if crashes is not None:
        crashes.mkdir(parents=True, exist_ok=True)
        path = crashes / f"{name}-{len(stats.examples)}{SUFFIX[name]}"
        path.write_bytes(data)
    stats.examples[signature] = (
        str(path) if path else None,
        message.strip().splitlines()[0][:160] if message.strip() else "",
    )


def summary_rows(results: list[TargetStats]) -> list[dict]:
    rows = []
    for stats in results:
        rows.append(
            {
                "target": stats.name,
                "cases": stats.cases,
                "per_second": round(stats.cases / max(stats.seconds, 1e-9), 1),
                "loaded": stats.ok,
                "rejected (PghmError)": sum(stats.rejected.values()),
                "error types": ", ".join(f"{k} {v}" for k, v in stats.rejected.most_common()),
                "unexpected": sum(stats.unexpected.values()),
            }
        )
    return rows


def format_table(rows: list[dict]) -> str:
    columns = list(rows[0])
    cells = [[str(row[c]) for c in columns] for row in rows]
    widths = [max(len(c), *(len(r[i]) for r in cells)) for i, c in enumerate(columns)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(columns, widths)), "  ".join("-" * w for w in widths)]
    lines += ["  ".join(v.ljust(w) for v, w in zip(row, widths)) for row in cells]
    return "\n".join(lines)


def fuzz(budget: float, seed: int, names: list[str], crashes: Path | None) -> list[TargetStats]:
    """Run ``names`` for ``budget`` seconds in all (set-up excluded)."""
    unknown = sorted(set(names) - set(TARGETS))
    if unknown:
        raise SystemExit(f"unknown targets {unknown}; choose from {', '.join(TARGETS)}")
    with tempfile.TemporaryDirectory(prefix="pghm-fuzz-") as workdir:
        targets = Targets(Path(workdir))
        return [run_target(targets, name, budget / len(names), seed, crashes) for name in names]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--budget", type=float, default=60.0, help="seconds of fuzzing in all (default 60)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--targets", default=",".join(TARGETS), help=f"comma-separated subset of {','.join(TARGETS)}")
    parser.add_argument("--json", type=Path, help="write the results here as JSON")
    parser.add_argument("--crashes", type=Path, help="save each distinct unexpected input here")
    args = parser.parse_args(argv)
    if not (math.isfinite(args.budget) and args.budget > 0):
        parser.error("--budget must be a positive number of seconds")
    torch.set_num_threads(2)
    warnings.simplefilter("ignore")  # mutants trip numpy's cast warnings by the thousand
    logging.getLogger("pghm").setLevel(logging.ERROR)  # nor "skipping image" for every damaged subject
    results = fuzz(args.budget, args.seed, args.targets.split(","), args.crashes)
    rows = summary_rows(results)
    print(format_table(rows))
    findings = [
        (stats.name, signature, count, stats.examples[signature])
        for stats in results
        for signature, count in stats.unexpected.items()
    ]
    if findings:
        print("\nunexpected exceptions (each a bug: loaders must raise PghmError only):")
        for name, signature, count, (path, message) in findings:
            print(f"  {name}: {signature} x{count}: {message}" + (f" [{path}]" if path else ""))
    else:
        print("\nno unexpected exceptions: every rejected input raised a one-line PghmError")
    if args.json:
        payload = {
            "budget_seconds": args.budget,
            "seed": args.seed,
            "rows": rows,
            "findings": [
                {"target": n, "exception": s, "count": c, "message": m, "reproducer": p} for n, s, c, (p, m) in findings
            ],
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(payload, indent=2) + "\n")
    return 1 if findings else 0


if __name__ == "__main__":
    sys.exit(main())
