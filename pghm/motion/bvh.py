"""BVH (Biovision Hierarchy) motion files: a strict, fast reader.

A BVH file has two sections::

    HIERARCHY
    ROOT Hips
    {
        OFFSET 0 0 0
        CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
        JOINT Chest
        {
            OFFSET 0 10.3 0
            CHANNELS 3 Zrotation Xrotation Yrotation
            End Site
            {
                OFFSET 0 12 0
            }
        }
    }
    MOTION
    Frames: 2
    Frame Time: 0.0333333
    0 93 0 0 0 0 0 0 0
    0 93 1 5 0 0 0 2 0

OFFSET is a joint's head relative to its parent's head in the rest pose, in the file's
units. Each frame row lists every joint's channels in hierarchy order. Rotation channels
are Euler angles in degrees, composed in the order written, each about the joint's own
(already rotated) axes: channels "Zrotation Xrotation Yrotation" with angles (a, b, c) give
the local rotation

    Q = R_z(a) R_x(b) R_y(c)

and the joint's rest-relative world rotation is G_j = G_parent(j) Q_j (all Q = I is the
rest pose, so G is "rest-aligned" as in :mod:`pghm.body.pose`). The head of joint j is
p_j = p_parent(j) + G_parent(j) offset_j; a root with position channels sits at them.

Every malformed input raises one :class:`~pghm.errors.MotionFileError` naming the problem
and, where there is one, the line; no other exception leaves :func:`load_bvh` or
:func:`parse_bvh`.
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pghm.errors import MotionFileError
from pghm.motion.motion import MAX_FPS, MAX_FRAMES

POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
CHANNEL_KINDS = POSITION_CHANNELS + ROTATION_CHANNELS
_CHANNEL_BY_LOWER = {name.lower(): name for name in CHANNEL_KINDS}

MAX_BVH_BYTES = 512 * 2**20
"""Largest file read (512 MiB): MAX_FRAMES rows of a 60-joint, 6-channel rig at ~10
characters a number take ~360 MB."""
MIN_FRAME_TIME = 1.0 / MAX_FPS
"""Shortest frame time accepted (seconds): the motion files' highest frame rate. A shorter one
(a denormal such as 5e-324) would make the frame rate overflow to infinity."""
MAX_JOINTS = 1024
MAX_VALUE = 1e6
"""Largest |value| of an OFFSET or a channel: 1 km in millimetres, 2,777 turns in degrees. Larger
numbers are corrupt data that would overflow float32 once retargeted (a 1e40 position did)."""
"""More joints than any motion-capture rig (full hands and face are a few hundred)."""

_COUNT_RE = re.compile(r"[0-9]{1,15}")
"""A count: ASCII digits only (``str.isdigit`` accepts superscripts that ``int`` rejects),
short enough that ``int`` is instant."""
_FRAMES_RE = re.compile(r"^\s*Frames\s*:\s*(\S*)\s*$", re.IGNORECASE)
_FRAME_TIME_RE = re.compile(r"^\s*Frame\s+Time\s*:\s*(\S*)\s*$", re.IGNORECASE)


@dataclass(frozen=True)
class BvhClip:
    """The contents of a BVH file.

    Attributes:
        names: J joint names, in file order (parents before children).
        parents: J parent indices, -1 for the root (joint 0).
        offsets: (J, 3) float64 rest offset of each joint's head from its parent's.
        channels: per joint, its channel names in file order (see :data:`CHANNEL_KINDS`).
        end_sites: (joint index, (3,) offset) of every End Site, the tips of the chains.
        frame_time: seconds per frame.
        values: (F, C) float64 channel values of every frame, C = total channel count.
        source: the file the clip came from, for messages.
    """

    names: list[str]
    parents: list[int]
    offsets: np.ndarray
    channels: list[tuple[str, ...]]
    end_sites: list[tuple[int, np.ndarray]]
    frame_time: float
    values: np.ndarray
    source: str = "<bvh>"

    @property
    def num_frames(self) -> int:
        return self.values.shape[0]

    @property
    def num_joints(self) -> int:
        return len(self.names)

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    def channel_columns(self, joint: int) -> range:
        """Columns of ``values`` holding joint ``joint``'s channels."""
        start = sum(len(c) for c in self.channels[:joint])
        return range(start, start + len(self.channels[joint]))

    def rest_positions(self) -> np.ndarray:
        """(J, 3) joint heads in the rest pose: sums of offsets along each chain."""
        positions = np.zeros((self.num_joints, 3))
        for joint, parent in enumerate(self.parents):
            positions[joint] = self.offsets[joint] + (positions[parent] if parent >= 0 else 0.0)
        return positions

    def local_rotations(self, frames: slice = slice(None)) -> np.ndarray:
        """(F, J, 3, 3) rotation of each joint relative to its parent (identity without
        channels), for the ``frames`` given (default all)."""
        values = self.values[frames]
        local = np.broadcast_to(np.eye(3), (len(values), self.num_joints, 3, 3)).copy()
        for joint in range(self.num_joints):
            columns = list(self.channel_columns(joint))
            order = "".join(c[0] for c in self.channels[joint] if c in ROTATION_CHANNELS)
            rotation_columns = [
                col for col, c in zip(columns, self.channels[joint], strict=True) if c in ROTATION_CHANNELS
            ]
            if order:
                local[:, joint] = euler_to_matrices(values[:, rotation_columns], order)
        return local

    def global_rotations(self, frames: slice = slice(None)) -> np.ndarray:
        """(F, J, 3, 3) rest-relative world rotation of each joint, G_j = G_parent(j) Q_j,
        for the ``frames`` given (default all)."""
        world = self.local_rotations(frames)
        for joint, parent in enumerate(self.parents):
            if parent >= 0:
                world[:, joint] = world[:, parent] @ world[:, joint]
        return world

    def joint_positions(self) -> np.ndarray:
        """(F, J, 3) joint heads in every frame: p_j = p_parent(j) + G_parent(j) offset_j,
        the root at :meth:`root_positions`. Position channels of other joints are ignored
        (exporters disagree on their meaning; they repeat the OFFSET in practice)."""
        world = self.global_rotations()
        positions = np.empty((self.num_frames, self.num_joints, 3))
        positions[:, 0] = self.root_positions()
        for joint, parent in enumerate(self.parents[1:], start=1):
            positions[:, joint] = positions[:, parent] + world[:, parent] @ self.offsets[joint]
        return positions

    def root_positions(self) -> np.ndarray:
        """(F, 3) the root's head: its position channels, its OFFSET on axes without one."""
        positions = np.broadcast_to(self.offsets[0], (self.num_frames, 3)).copy()
        for column, channel in zip(self.channel_columns(0), self.channels[0], strict=True):
            if channel in POSITION_CHANNELS:
                positions[:, POSITION_CHANNELS.index(channel)] = self.values[:, column]
        return positions


def axis_rotations(axis: str, degrees: np.ndarray) -> np.ndarray:
    """(N, 3, 3) right-handed rotations by ``degrees`` (N,) about the world axis "X", "Y" or "Z"."""
    radians = np.radians(degrees)
    cos, sin = np.cos(radians), np.sin(radians)
    one, zero = np.ones_like(radians), np.zeros_like(radians)
    rows = {
        "X": ((one, zero, zero), (zero, cos, -sin), (zero, sin, cos)),
        "Y": ((cos, zero, sin), (zero, one, zero), (-sin, zero, cos)),
        "Z": ((cos, -sin, zero), (sin, cos, zero), (zero, zero, one)),
    }[axis]
    return np.stack([np.stack(row, -1) for row in rows], -2)


def euler_to_matrices(degrees: np.ndarray, order: str) -> np.ndarray:
    """Rotation matrices of BVH Euler angles.

    Args:
        degrees: (N, K) angles in degrees, one column per letter of ``order``.
        order: K axis letters in channel order, e.g. "ZXY".

    Returns:
        (N, 3, 3) R = R_order[0](degrees[:, 0]) R_order[1](degrees[:, 1]) ...: intrinsic
        rotations in the written order (equivalently, extrinsic in the reverse order).
    """
    result = axis_rotations(order[0], degrees[:, 0])
    for k in range(1, len(order)):
        result = result @ axis_rotations(order[k], degrees[:, k])
    return result


class _Tokens:
    """Whitespace-separated tokens of the hierarchy with their 1-based line numbers."""

    def __init__(self, lines: list[str], where: str) -> None:
        self.items = [(token, number) for number, line in enumerate(lines, 1) for token in line.split()]
        self.position = 0
        self.where = where
        self.last_line = len(lines)

    def error(self, message: str, line: int | None = None) -> MotionFileError:
        line = self.last_line if line is None else line
        return MotionFileError(f"{self.where}: line {line}: {message}")

    def peek(self) -> tuple[str, int] | None:
        return self.items[self.position] if self.position < len(self.items) else None

    def next(self, expected: str) -> tuple[str, int]:
        item = self.peek()
        if item is None:
            raise self.error(f"the hierarchy ends before MOTION where {expected} was expected")
        self.position += 1
        return item

    def rest_of_line(self, line: int) -> list[str]:
        """Tokens remaining on ``line``, up to a "{" (left in place)."""
        taken = []
        while (item := self.peek()) is not None and item[1] == line and item[0] != "{":
            taken.append(item[0])
            self.position += 1
        return taken

    def number(self, what: str) -> float:
        token, line = self.next(what)
        try:
            value = float(token)
        except ValueError:
            raise self.error(f"{what}: '{token}' is not a number", line) from None
        if not abs(value) <= MAX_VALUE:
            raise self.error(f"{what}: '{token}' is not a finite number within +-{MAX_VALUE:g}", line)
        return value


@dataclass
class _Block:
    """An open ``{ ... }`` of the hierarchy: a joint, or the End Site of ``joint``."""

    joint: int
    end_site: bool
    line: int
    offset: np.ndarray | None = None
    has_channels: bool = False


def _parse_hierarchy(
    lines: list[str], where: str
) -> tuple[list[str], list[int], np.ndarray, list[tuple[str, ...]], list[tuple[int, np.ndarray]]]:
    """Names, parents, offsets, channels and End Sites of the HIERARCHY section's ``lines``.

    An explicit stack of open blocks instead of recursion, so no nesting depth can
    overflow the interpreter's stack.
    """
    tokens = _Tokens(lines, where)
    first = tokens.peek()
    if first is None or first[0].upper() != "HIERARCHY":
        found = "nothing" if first is None else f"'{first[0][:40]}'"
        raise tokens.error("missing HIERARCHY: the file must start with it, found " + found, first[1] if first else 1)
    tokens.next("HIERARCHY")
    names: list[str] = []
    parents: list[int] = []
    offsets: list[np.ndarray] = []
    channels: list[tuple[str, ...]] = []
    end_sites: list[tuple[int, np.ndarray]] = []
    stack: list[_Block] = []

    def open_block(keyword: str, line: int) -> None:
        if keyword == "END":
            site, site_line = tokens.next("'Site' after 'End'")
            if site.lower() != "site":
                raise tokens.error(f"expected 'End Site', found 'End {site[:40]}'", site_line)
            if not stack or stack[-1].end_site:
                raise tokens.error("End Site outside a joint", line)
            block = _Block(stack[-1].joint, True, line)
        else:
            name = " ".join(tokens.rest_of_line(line))
            if not name:
                raise tokens.error(f"{keyword} without a name", line)
            if name in names:
                raise tokens.error(f"duplicate joint name '{name}'", line)
            if len(names) >= MAX_JOINTS:
                raise tokens.error(f"more than {MAX_JOINTS} joints", line)
            names.append(name)
            parents.append(stack[-1].joint if stack else -1)
            offsets.append(np.zeros(3))
            channels.append(())
            block = _Block(len(names) - 1, False, line)
        label = "End Site" if keyword == "END" else f"{keyword} {names[-1][:40]}"
        brace, brace_line = tokens.next(f"'{{' opening {label}")
        if brace != "{":
            raise tokens.error(f"expected '{{' after {label}, found '{brace[:40]}'", brace_line)
        stack.append(block)

    keyword, line = tokens.next("ROOT")
    if keyword.upper() != "ROOT":
        raise tokens.error(f"expected ROOT after HIERARCHY, found '{keyword[:40]}'", line)
    open_block("ROOT", line)
    while stack:
        token, line = tokens.next(f"'}}' closing '{names[stack[-1].joint]}' (unbalanced braces)")
        word = token.upper()
        block = stack[-1]
        if word == "OFFSET":
            if block.offset is not None:
                raise tokens.error("second OFFSET in one block", line)
            block.offset = np.array([tokens.number(f"OFFSET of '{names[block.joint]}'") for _ in range(3)])
        elif word == "CHANNELS":
            if block.end_site:
                raise tokens.error("an End Site cannot have CHANNELS", line)
            if block.has_channels:
                raise tokens.error(f"second CHANNELS line for joint '{names[block.joint]}'", line)
            channels[block.joint] = _parse_channels(tokens, line)
            block.has_channels = True
        elif word in ("JOINT", "END"):
            if block.end_site:
                raise tokens.error(f"{token} inside an End Site", line)
            open_block(word, line)
        elif token == "}":
            if block.offset is None:
                what = f"End Site of '{names[block.joint]}'" if block.end_site else f"joint '{names[block.joint]}'"
                raise tokens.error(f"{what} has no OFFSET", block.line)
            if block.end_site:
                end_sites.append((block.joint, block.offset))
            else:
                offsets[block.joint] = block.offset
            stack.pop()
        elif word == "ROOT":
            raise tokens.error("ROOT inside a joint (unbalanced braces?)", line)
        else:
            raise tokens.error(f"unexpected '{token[:40]}' in the hierarchy", line)
    if (item := tokens.peek()) is not None:
        if item[0].upper() == "ROOT":
            raise tokens.error("a second ROOT: files with several skeletons are not supported", item[1])
        if item[0] == "}":
            raise tokens.error("'}' without a matching '{' (unbalanced braces)", item[1])
        raise tokens.error(f"unexpected '{item[0][:40]}' after the ROOT block", item[1])
    return names, parents, np.stack(offsets), channels, end_sites


def _parse_channels(tokens: _Tokens, line: int) -> tuple[str, ...]:
    count_token, count_line = tokens.next("the channel count")
    if not _COUNT_RE.fullmatch(count_token) or int(count_token) > len(CHANNEL_KINDS):
        raise tokens.error(f"CHANNELS count must be 0 to {len(CHANNEL_KINDS)}, found '{count_token[:40]}'", count_line)
    names = []
    for _ in range(int(count_token)):
        token, token_line = tokens.next("a channel name")
        if token_line != line:
            raise tokens.error(f"CHANNELS {count_token} lists only {len(names)} channel names", line)
        name = _CHANNEL_BY_LOWER.get(token.lower())
        if name is None:
            raise tokens.error(
                f"unknown channel '{token[:40]}', expected one of {', '.join(CHANNEL_KINDS)}", token_line
            )
        if name in names:
            raise tokens.error(f"channel '{name}' listed twice", token_line)
        names.append(name)
    if (item := tokens.peek()) is not None and item[1] == line and _CHANNEL_BY_LOWER.get(item[0].lower()):
        raise tokens.error(f"CHANNELS {count_token} lists more channel names than that", line)
    return tuple(names)


def _header_value(lines: list[str], index: int, pattern: re.Pattern, what: str, where: str) -> str:
    if index >= len(lines):
        raise MotionFileError(f"{where}: the MOTION section ends before '{what}:'")
    match = pattern.match(lines[index])
    if match is None:
        raise MotionFileError(
            f"{where}: line {index + 1}: expected '{what}: <value>', found '{lines[index].strip()[:60]}'"
        )
    return match.group(1)


def _parse_motion(lines: list[str], start: int, num_channels: int, where: str) -> tuple[float, np.ndarray]:
    """Frame time and (F, C) values of the MOTION section, whose header is ``lines[start]``."""
    body = [i for i in range(start + 1, len(lines)) if lines[i].strip()]
    frames_text = _header_value(lines, body[0] if body else len(lines), _FRAMES_RE, "Frames", where)
    if not _COUNT_RE.fullmatch(frames_text):
        raise MotionFileError(f"{where}: line {body[0] + 1}: frame count '{frames_text[:40]}' is not a whole number")
    frames = int(frames_text)
    if frames == 0:
        raise MotionFileError(f"{where}: the file has zero frames")
    if frames > MAX_FRAMES:
        raise MotionFileError(f"{where}: the file claims {frames} frames, more than the {MAX_FRAMES} accepted")
    time_text = _header_value(lines, body[1] if len(body) > 1 else len(lines), _FRAME_TIME_RE, "Frame Time", where)
    try:
        frame_time = float(time_text)
    except ValueError:
        raise MotionFileError(f"{where}: line {body[1] + 1}: frame time '{time_text[:40]}' is not a number") from None
    if not (np.isfinite(frame_time) and frame_time >= MIN_FRAME_TIME):
        raise MotionFileError(
            f"{where}: line {body[1] + 1}: frame time must be a number of seconds of at least "
            f"{MIN_FRAME_TIME:g}, got {time_text[:40]}"
        )
    rows = body[2:]
    if len(rows) != frames:
        raise MotionFileError(f"{where}: the file declares {frames} frames but has {len(rows)} data rows")
    if num_channels == 0:
        raise MotionFileError(f"{where}: the skeleton has no channels, so its frames hold no motion")
    text = "\n".join(lines[i] for i in rows)
    try:
        values = np.loadtxt(io.StringIO(text), dtype=np.float64, comments=None, ndmin=2)
    except ValueError:
        raise _row_error(lines, rows, num_channels, where) from None
    if values.shape != (frames, num_channels):
        raise _row_error(lines, rows, num_channels, where)
    sane = np.abs(values) <= MAX_VALUE  # False for NaN too
    if not sane.all():
        row, column = np.argwhere(~sane)[0]
        raise MotionFileError(
            f"{where}: line {rows[row] + 1}: value {column + 1} is {values[row, column]:g}, "
            f"not a finite number within +-{MAX_VALUE:g}"
        )
    return frame_time, values


def _row_error(lines: list[str], rows: list[int], num_channels: int, where: str) -> MotionFileError:
    """The error for the first bad data row (the slow path, taken only for broken files)."""
    for index in rows:
        tokens = lines[index].split()
        if len(tokens) != num_channels:
            return MotionFileError(
                f"{where}: line {index + 1}: {len(tokens)} values, the hierarchy has {num_channels} channels"
            )
        for column, token in enumerate(tokens):
            try:
                float(token)
            except ValueError:
                return MotionFileError(f"{where}: line {index + 1}: value {column + 1} '{token[:40]}' is not a number")
    return MotionFileError(f"{where}: unreadable frame data")


def _decode(data: bytes, where: str) -> str:
    if not data.strip():
        raise MotionFileError(f"{where}: the file is empty")
    nul = data.find(b"\x00")
    if nul >= 0:
        raise MotionFileError(f"{where}: binary data (a NUL byte at offset {nul}), not a BVH text file")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        raise MotionFileError(f"{where}: not UTF-8 text (invalid byte at offset {error.start})") from None


def parse_bvh(data: bytes | str, source: str = "<bvh>") -> BvhClip:
    """Parse BVH file contents; any problem is one :class:`MotionFileError`.

    Args:
        data: the file's bytes (must be UTF-8) or text.
        source: name used in error messages and kept in the clip.
    """
    text = _decode(data, source) if isinstance(data, bytes) else data
    if not text.strip():
        raise MotionFileError(f"{source}: the file is empty")
    lines = text.splitlines()
    motion = next((i for i, line in enumerate(lines) if line.strip().upper() == "MOTION"), None)
    if motion is None:
        raise MotionFileError(f"{source}: missing MOTION section (no line reading 'MOTION')")
    names, parents, offsets, channels, end_sites = _parse_hierarchy(lines[:motion], source)
    num_channels = sum(len(c) for c in channels)
    frame_time, values = _parse_motion(lines, motion, num_channels, source)
    return BvhClip(names, parents, offsets, channels, end_sites, frame_time, values, source)


def load_bvh(path: str | Path) -> BvhClip:
    """Read a ``.bvh`` file; any problem is one :class:`MotionFileError` naming it."""
    path = Path(path)
    try:
        size = path.stat().st_size
        if not path.is_file():
            raise MotionFileError(f"{path}: not a file")
        if size > MAX_BVH_BYTES:
            raise MotionFileError(f"{path}: {size} bytes, larger than the {MAX_BVH_BYTES} accepted")
        data = path.read_bytes()
    except FileNotFoundError:
        raise MotionFileError(f"{path}: BVH file not found") from None
    except OSError as error:
        raise MotionFileError(f"{path}: cannot read ({error.strerror or error})") from None
    return parse_bvh(data, str(path))
