"""The BVH reader: real files, Euler conventions against axis-by-axis composition, and every
kind of malformed input raising one MotionFileError that names the problem."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import roma
import torch
from geometry import rodrigues
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pghm.errors import MotionFileError
from pghm.motion.bvh import MAX_BVH_BYTES, euler_to_matrices, load_bvh, parse_bvh
from pghm.motion.motion import MAX_FRAMES

MOTION_DIR = Path(__file__).resolve().parent.parent / "assets" / "motion"
AXES = {"X": np.array([1.0, 0.0, 0.0]), "Y": np.array([0.0, 1.0, 0.0]), "Z": np.array([0.0, 0.0, 1.0])}

SMALL = (Path(__file__).parent / "data" / "two_bone.bvh").read_text()
"""A two-bone clip (hips with translation, chest), two frames: the base of the malformed cases."""


def test_reads_the_mixamo_clip():
    clip = load_bvh(MOTION_DIR / "mixamo_walk_69f.bvh")
    assert clip.num_frames == 69 and clip.fps == pytest.approx(30.0, rel=1e-5)
    assert clip.names[0] == "mixamorig:Hips" and clip.parents[0] == -1
    assert clip.num_joints == 55  # 54 named in SOURCE.md plus HeadTop_End, which carries channels
    assert clip.channels[0] == ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")
    assert clip.channels[1] == ("Zrotation", "Yrotation", "Xrotation")
    assert clip.values.shape == (69, 6 + 3 * 54)
    # OFFSET of LeftForeArm as written in the file.
    np.testing.assert_allclose(clip.offsets[clip.names.index("mixamorig:LeftForeArm")], [27.3517, -0.9645, -1.4034])


def test_reads_the_mocapbank_clip():
    clip = load_bvh(MOTION_DIR / "mocapbank_455f.bvh")
    assert clip.num_frames == 455 and clip.num_joints == 19
    assert clip.channels[0][3:] == ("Zrotation", "Xrotation", "Yrotation")
    assert [clip.names[p] for p in clip.parents[1:4]] == ["Hips", "Chest", "Chest2"]
    assert len(clip.end_sites) == 5  # head, two wrists, two ankles
    # The first value of the first row, as written.
    assert clip.values[0, 0] == pytest.approx(-44.0003)


def test_small_file_forward_kinematics():
    clip = parse_bvh(SMALL)
    np.testing.assert_allclose(clip.root_positions(), [[0, 90, 0], [1, 91, 2]])
    np.testing.assert_allclose(clip.rest_positions(), [[0, 0, 0], [0, 10, 0]])
    world = clip.global_rotations()
    # Frame 1: root Zrotation 90 turns the chest's +y offset to -x; the chest adds Xrotation 30.
    np.testing.assert_allclose(world[1, 0] @ [0, 10, 0], [-10, 0, 0], atol=1e-12)
    np.testing.assert_allclose(
        world[1, 1], rodrigues(np.radians(90) * AXES["Z"]) @ rodrigues(np.radians(30) * AXES["X"]), atol=1e-12
    )


@pytest.mark.parametrize("name", ["mixamo_walk_69f.bvh", "mocapbank_455f.bvh"])
def test_joint_positions_match_a_textbook_reading(name):
    from test_motion_retarget import naive_bvh_joint_positions

    names, expected = naive_bvh_joint_positions(MOTION_DIR / name)
    clip = load_bvh(MOTION_DIR / name)
    assert clip.names == names
    np.testing.assert_allclose(clip.joint_positions(), expected, atol=1e-9)  # cm; float64 round-off


@settings(max_examples=200, deadline=None)
@given(
    order=st.permutations("XYZ").map("".join) | st.sampled_from(["X", "Y", "Z", "ZX", "YZ", "XY"]),
    angles=st.lists(st.floats(-720.0, 720.0, allow_nan=False), min_size=3, max_size=3),
)
def test_euler_matrix_is_the_product_of_axis_rotations(order, angles):
    """R = R_a1(t1) R_a2(t2) ... with each factor built independently by Rodrigues' formula."""
    degrees = np.array(angles[: len(order)])
    expected = np.eye(3)
    for axis, angle in zip(order, degrees, strict=True):
        expected = expected @ rodrigues(np.radians(angle) * AXES[axis])
    got = euler_to_matrices(degrees[None], order)[0]
    np.testing.assert_allclose(got, expected, atol=1e-12)  # float64 round-off of a few products
    if len(order) == 3:
        # roma's upper-case conventions are intrinsic rotations in the order written.
        reference = roma.euler_to_rotmat(order, torch.tensor(degrees), degrees=True).numpy()
        np.testing.assert_allclose(got, reference, atol=1e-9)  # roma composes through quaternions


def _replace(text: str, old: str, new: str) -> str:
    assert old in text
    return text.replace(old, new, 1)


MALFORMED = {
    "empty": ("", "empty"),
    "blank": ("  \n\n \t\n", "empty"),
    "no hierarchy": (SMALL.replace("HIERARCHY\n", ""), "missing HIERARCHY"),
    "no motion": (SMALL.split("MOTION")[0], "missing MOTION"),
    "no frames line": (_replace(SMALL, "Frames: 2\n", ""), "Frames"),
    "zero frames": (_replace(SMALL, "Frames: 2", "Frames: 0"), "zero frames"),
    "negative frames": (_replace(SMALL, "Frames: 2", "Frames: -3"), "not a whole number"),
    "absurd frames": (_replace(SMALL, "Frames: 2", f"Frames: {10**6}"), "more than"),
    "superscript frames": (_replace(SMALL, "Frames: 2", "Frames: \u00b2"), "not a whole number"),
    "huge frames": (_replace(SMALL, "Frames: 2", "Frames: " + "9" * 5000), "not a whole number"),
    "bad frame time": (_replace(SMALL, "Frame Time: 0.04", "Frame Time: fast"), "frame time"),
    "zero frame time": (_replace(SMALL, "Frame Time: 0.04", "Frame Time: 0"), "frame time"),
    "nan frame time": (_replace(SMALL, "Frame Time: 0.04", "Frame Time: nan"), "frame time"),
    "short row": (_replace(SMALL, "1 91 2 90 0 0 0 30 0", "1 91 2 90 0 0 0 30"), "line 20: 8 values"),
    "long row": (_replace(SMALL, "1 91 2 90 0 0 0 30 0", "1 91 2 90 0 0 0 30 0 7"), "line 20: 10 values"),
    "missing row": (_replace(SMALL, "1 91 2 90 0 0 0 30 0\n", ""), "declares 2 frames but has 1"),
    "extra row": (SMALL + "0 0 0 0 0 0 0 0 0\n", "declares 2 frames but has 3"),
    "non-numeric value": (_replace(SMALL, "1 91 2 90", "1 91 two 90"), "'two' is not a number"),
    "nan value": (_replace(SMALL, "1 91 2 90", "1 nan 2 90"), "not a finite number"),
    "inf value": (_replace(SMALL, "1 91 2 90", "1 91 2 -inf"), "not a finite number"),
    "overflowing value": (_replace(SMALL, "1 91 2 90", "1 91 2 1e999"), "not a finite number"),
    "unknown channel": (
        _replace(SMALL, "Zrotation Xrotation Yrotation\n  JOINT", "Zrotation Xrotation Wrotation\n  JOINT"),
        "unknown channel 'Wrotation'",
    ),
    "channel count too big": (_replace(SMALL, "CHANNELS 3", "CHANNELS 9"), "CHANNELS count"),
    "channel count mismatch": (_replace(SMALL, "CHANNELS 3", "CHANNELS 2"), "more channel names"),
    "too few channel names": (_replace(SMALL, "CHANNELS 3", "CHANNELS 4"), "lists only 3"),
    "duplicate channel": (
        _replace(SMALL, "Zrotation Xrotation Yrotation\n  JOINT", "Zrotation Zrotation Yrotation\n  JOINT"),
        "listed twice",
    ),
    "missing close brace": (_replace(SMALL, "  }\n}\nMOTION", "  }\nMOTION"), "unbalanced braces"),
    "extra close brace": (_replace(SMALL, "}\nMOTION", "}\n}\nMOTION"), "unbalanced braces"),
    "missing open brace": (_replace(SMALL, "JOINT Chest\n  {", "JOINT Chest\n"), "expected '{' after JOINT Chest"),
    "bad offset": (_replace(SMALL, "OFFSET 0 10 0", "OFFSET 0 ten 0"), "OFFSET of 'Chest': 'ten' is not a number"),
    "nan offset": (_replace(SMALL, "OFFSET 0 10 0", "OFFSET 0 nan 0"), "not a finite number"),
    "missing offset": (_replace(SMALL, "    OFFSET 0 10 0\n", ""), "joint 'Chest' has no OFFSET"),
    "duplicate joint": (_replace(SMALL, "JOINT Chest", "JOINT Hips"), "duplicate joint name 'Hips'"),
    "nameless joint": (_replace(SMALL, "JOINT Chest", "JOINT"), "JOINT without a name"),
    "unknown keyword": (_replace(SMALL, "OFFSET 0 10 0", "OFFSET 0 10 0\n    SCALE 2"), "unexpected 'SCALE'"),
    "two roots": (_replace(SMALL, "MOTION", "ROOT Other\n{\n OFFSET 0 0 0\n}\nMOTION"), "second ROOT"),
    "channels in end site": (
        _replace(SMALL, "OFFSET 0 5 0", "OFFSET 0 5 0\n CHANNELS 1 Xrotation"),
        "End Site cannot have CHANNELS",
    ),
    "no root": (_replace(SMALL, "ROOT Hips", "JOINT Hips"), "expected ROOT"),
}


@pytest.mark.parametrize("name", list(MALFORMED))
def test_malformed_bvh_raises_one_clear_error(name):
    text, expected = MALFORMED[name]
    with pytest.raises(MotionFileError) as info:
        parse_bvh(text.encode(), "clip.bvh")
    message = str(info.value)
    assert expected in message, message
    assert message.startswith("clip.bvh: ") and "\n" not in message


def test_absurd_frame_count_is_rejected_before_reading_rows():
    """Refused from the header: the parse allocates less than one float64 per claimed frame
    (tracemalloc sees numpy's buffers), so nothing was sized by the claim."""
    text = _replace(SMALL, "Frames: 2", f"Frames: {MAX_FRAMES + 1}")
    tracemalloc.start()
    try:
        with pytest.raises(MotionFileError, match="more than"):
            parse_bvh(text)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < (MAX_FRAMES + 1) * np.dtype(np.float64).itemsize, peak


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", "binary data"),
        (SMALL.replace("Chest", "Br\u00fcst").encode("latin-1"), "not UTF-8"),
        (b"\xff\xfe" + SMALL.encode("utf-16-le"), "binary data"),
        (bytes(range(256)), "binary data"),
    ],
)
def test_non_text_input_raises(data, expected):
    with pytest.raises(MotionFileError, match=expected):
        parse_bvh(data, "clip.bvh")


def test_utf8_names_bom_crlf_and_tabs_are_accepted():
    text = "\ufeff" + SMALL.replace("Chest", "Br\u00fcst").replace("\n", "\r\n").replace("  ", "\t")
    clip = parse_bvh(text.encode())
    assert clip.names == ["Hips", "Br\u00fcst"]
    np.testing.assert_array_equal(clip.values, parse_bvh(SMALL).values)


def test_load_bvh_file_errors(tmp_path):
    with pytest.raises(MotionFileError, match="not found"):
        load_bvh(tmp_path / "missing.bvh")
    with pytest.raises(MotionFileError, match="not a file"):
        load_bvh(tmp_path)
    big = tmp_path / "big.bvh"
    with open(big, "wb") as file:
        file.truncate(MAX_BVH_BYTES + 1)  # sparse: no disk used
    with pytest.raises(MotionFileError, match="larger than"):
        load_bvh(big)


def test_deep_nesting_does_not_overflow():
    depth = 5000
    joints = "".join(f"JOINT j{i}\n{{\nOFFSET 0 1 0\n" for i in range(depth))
    text = "HIERARCHY\nROOT r\n{\nOFFSET 0 0 0\n" + joints + "}\n" * depth + "}\nMOTION\nFrames: 1\nFrame Time: 1\n\n"
    with pytest.raises(MotionFileError, match="more than 1024 joints"):
        parse_bvh(text)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_mutated_files_parse_or_raise_motion_file_error(data):
    """Random cuts, insertions and byte flips of a valid file never raise anything else."""
    raw = bytearray(SMALL.encode())
    for _ in range(data.draw(st.integers(1, 4))):
        position = data.draw(st.integers(0, len(raw)))
        kind = data.draw(st.sampled_from(["cut", "insert", "flip"]))
        if kind == "cut":
            del raw[position : position + data.draw(st.integers(1, 20))]
        elif kind == "insert":
            raw[position:position] = data.draw(
                st.sampled_from([b"{", b"}", b" ", b"\n", b"nan", b"-", b"JOINT x\n", b"End Site", b"9" * 30])
            )
        elif raw:
            raw[min(position, len(raw) - 1)] = data.draw(st.integers(0, 255))
    try:
        clip = parse_bvh(bytes(raw), "fuzz.bvh")
    except MotionFileError:
        return
    assert clip.values.shape == (clip.num_frames, sum(len(c) for c in clip.channels))
    assert np.isfinite(clip.values).all()
