"""The capture readers: frames, stride, max frames, crop and resize, rotation, image folders, bad files."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
from capture_videos import (
    ffmpeg,
    truncated_video,
    with_rotation,
    with_sample_aspect,
    write_encoded,
    write_flat_hdr_video,
    write_hlg_video,
    write_video,
)
from PIL import Image

from pghm.capture.crop import Region
from pghm.capture.video import REFERENCE_WHITE_NITS, open_source, scaled_size
from pghm.errors import PghmError

COMPRESSION_TOLERANCE = 12
"""Grey levels H.264 (yuv420p, best quality) may move a flat test pattern, away from its edges."""

GREY_STEP = 20
"""Frame k of the numbered video is flat grey 10 + 20 k: its mean says which frame it is."""


def numbered_frames(count: int, height: int = 48, width: int = 64) -> np.ndarray:
    levels = 10 + GREY_STEP * np.arange(count)
    return np.broadcast_to(levels[:, None, None, None], (count, height, width, 3)).astype(np.uint8)


def frame_number(image: np.ndarray) -> int:
    return int(round((image.mean() - 10) / GREY_STEP))


def quadrants(height: int, width: int) -> np.ndarray:
    """(H, W, 3) uint8: four flat colours, one per quadrant, so any turn or flip changes it."""
    image = np.zeros((height, width, 3), np.uint8)
    h, w = height // 2, width // 2
    image[:h, :w] = (230, 30, 30)
    image[:h, w:] = (30, 230, 30)
    image[h:, :w] = (30, 30, 230)
    image[h:, w:] = (230, 230, 30)
    return image


def interior(image: np.ndarray, border: int = 4) -> np.ndarray:
    """The image without pixels within ``border`` of a quadrant edge (where compression blurs colours)."""
    height, width = image.shape[:2]
    keep = np.ones((height, width), bool)
    for h in (0, height // 2, height):
        keep[max(0, h - border) : h + border] = False
    for w in (0, width // 2, width):
        keep[:, max(0, w - border) : w + border] = False
    return image[keep]


def read(source, region=None, out_size=None, every=1, max_frames=None):
    region = region or Region.full(source.width, source.height)
    out_size = out_size or (region.height, region.width)
    return list(source.frames(region, out_size, every, max_frames))


def test_every_frame_in_order(tmp_path):
    source = open_source(write_video(tmp_path / "numbered.mp4", numbered_frames(12)))
    assert source.fps == 10.0
    assert (source.width, source.height) == (64, 48)
    frames = read(source)
    assert [index for index, _ in frames] == list(range(12))
    assert [frame_number(image) for _, image in frames] == list(range(12))


@pytest.mark.parametrize(
    "every, max_frames, expected", [(3, None, [0, 3, 6, 9]), (2, 3, [0, 2, 4]), (5, 10, [0, 5, 10])]
)
def test_stride_and_max_frames(tmp_path, every, max_frames, expected):
    source = open_source(write_video(tmp_path / "numbered.mp4", numbered_frames(12)))
    frames = read(source, every=every, max_frames=max_frames)
    assert [index for index, _ in frames] == expected
    # The frame numbers are the source's: the content of frame k is frame k's.
    assert [frame_number(image) for _, image in frames] == expected


def test_crop_and_resize_match_the_frame(tmp_path):
    pattern = quadrants(96, 128)
    source = open_source(write_video(tmp_path / "quadrants.mp4", np.stack([pattern] * 2)))
    region = Region(32, 24, 64, 48)  # centred on the quadrants' meeting point (64, 48)
    size = scaled_size(region, 32)
    assert size == (24, 32)
    (_, image), _ = read(source, region, size)
    assert image.shape == (24, 32, 3)
    expected = quadrants(24, 32)
    assert np.abs(interior(image).astype(int) - interior(expected)).max() <= COMPRESSION_TOLERANCE


@pytest.mark.parametrize(
    "codec, pixel_format, suffix",
    [("libx264", "yuv420p", "mp4"), ("libx265", "yuv420p10le", "mp4"), ("prores_ks", "yuv422p10le", "mov")],
)
def test_crop_at_odd_offsets_keeps_the_colours(tmp_path, codec, pixel_format, suffix):
    """Phones record 10-bit HEVC, iPhones ProRes 422 too: an exact crop at odd offsets must not
    scramble a deep format's colours."""
    pattern = quadrants(96, 128)
    source = open_source(write_encoded(tmp_path / f"deep.{suffix}", np.stack([pattern] * 2), codec, pixel_format))
    assert source.deep == (pixel_format != "yuv420p")
    region = Region(33, 25, 62, 46)  # odd offsets, centred on the quadrants' meeting point (64, 48)
    (_, image), _ = read(source, region)
    assert np.abs(interior(image).astype(int) - interior(quadrants(46, 62))).max() <= COMPRESSION_TOLERANCE


def test_never_enlarged():
    assert scaled_size(Region(0, 0, 200, 100), 512) == (100, 200)
    assert scaled_size(Region(0, 0, 1080, 1920), 512) == (512, 288)


def test_rotated_video_comes_out_upright(tmp_path):
    """A phone stores a portrait video as landscape frames plus "turn 90 degrees anticlockwise to show"."""
    upright = quadrants(96, 64)
    stored = np.rot90(upright, k=-1)  # what the sensor recorded: the upright picture turned clockwise
    base = write_video(tmp_path / "stored.mp4", np.stack([stored] * 3))
    source = open_source(with_rotation(base, tmp_path / "portrait.mp4", 90))
    assert (source.width, source.height) == (64, 96)
    frames = read(source)
    assert len(frames) == 3
    for _, image in frames:
        assert image.shape == upright.shape
        assert np.abs(interior(image).astype(int) - interior(upright)).max() <= COMPRESSION_TOLERANCE


def test_non_square_pixels_come_out_at_display_width(tmp_path):
    """Pixels stated twice as wide as tall: stored 64 wide, the picture is 128 wide on screen."""
    shown = quadrants(96, 128)
    stored = write_video(tmp_path / "stored.mp4", np.stack([shown[:, ::2]] * 2))
    source = open_source(with_sample_aspect(stored, tmp_path / "anamorphic.mp4", (2, 1)))
    assert (source.width, source.height) == (128, 96)
    region = Region(32, 24, 64, 48)
    (_, image), _ = read(source, region, (48, 64))
    assert np.abs(interior(image).astype(int) - interior(quadrants(48, 64))).max() <= COMPRESSION_TOLERANCE


def test_huge_frames_decode_scaled(tmp_path):
    pattern = quadrants(2160, 3840)
    source = open_source(write_video(tmp_path / "uhd.mp4", np.stack([pattern] * 2)))
    full = Region.full(source.width, source.height)
    frames = read(source, full, scaled_size(full, 512))
    assert [image.shape for _, image in frames] == [(288, 512, 3)] * 2
    assert np.abs(interior(frames[0][1]).astype(int) - interior(quadrants(288, 512))).max() <= COMPRESSION_TOLERANCE


HDR_ROUND_TRIP_TOLERANCE = 5.0
"""Mean grey levels the quadrants may move through BT.2020 HLG at 10 bits and back (3.7 measured):
a saturated primary's dark channels move by up to 13 inside a quadrant (the gamut conversion
subtracts nearly equal terms) and more at its chroma-subsampled edges. Read as SDR they move by 47,
turned the wrong way by 102."""

HLG_PEAK_NITS = 1000.0
"""The display HLG's system gamma is defined for here (ITU-R BT.2100: gamma 1.2 at 1000 cd/m^2)."""
SDR_DISPLAY_GAMMA = 2.4
"""BT.1886's display gamma: SDR's code value for display light L (relative to white) is L^(1/2.4)."""
QUANTISATION_TOLERANCE = 3
"""Grey levels between an exact conversion and one through 10-bit limited-range video."""


def hlg_display_nits(signal: float) -> float:
    """Display light of an HLG grey (BT.2100): scene light E = signal^2 / 3 (signal <= 1/2), else
    (exp((signal - c) / a) + b) / 12; display light 1000 E^1.2 cd/m^2."""
    a, b, c = 0.17883277, 0.28466892, 0.55991073
    scene = signal**2 / 3 if signal <= 0.5 else (np.exp((signal - c) / a) + b) / 12
    return HLG_PEAK_NITS * scene**1.2


def pq_signal(nits: float) -> float:
    """The PQ signal of display light ``nits`` (SMPTE ST 2084's inverse EOTF)."""
    m1, m2 = 2610 / 16384, 2523 / 4096 * 128
    c1, c2, c3 = 3424 / 4096, 2413 / 4096 * 32, 2392 / 4096 * 32
    y = (nits / 10000) ** m1
    return ((c1 + c2 * y) / (1 + c3 * y)) ** m2


@pytest.mark.parametrize(
    "transfer, signals, nits",
    [
        ("HLG", [0.0, 0.25, 0.5, 0.75], [hlg_display_nits(v) for v in (0.0, 0.25, 0.5, 0.75)]),
        ("PQ", [pq_signal(n) for n in (0.0, 20.0, 100.0, 203.0)], [0.0, 20.0, 100.0, 203.0]),
    ],
)
def test_hdr_video_reads_as_sdr_with_reference_white_at_white(tmp_path, transfer, signals, nits):
    """An iPhone records HLG; HDR's reference white (HLG 75 %, PQ 203 cd/m^2) must read as white, and
    a grey of display light L as SDR's 255 (L / 203)^(1/2.4), not as its HDR code value."""
    source = open_source(write_flat_hdr_video(tmp_path / f"{transfer}.mov", signals, transfer))
    assert source.transfer == transfer
    levels = [image.reshape(-1, 3) for _, image in read(source)]
    expected = [255 * min(1.0, n / REFERENCE_WHITE_NITS) ** (1 / SDR_DISPLAY_GAMMA) for n in nits]
    for level, value in zip(levels, expected, strict=True):
        assert np.abs(level.astype(float) - value).max() <= QUANTISATION_TOLERANCE
    assert expected[-1] == 255 and expected[1] > 60  # the test's own greys span the range


def test_iphone_video_portrait_hdr_reads_upright_in_sdr(tmp_path):
    """What an iPhone records: landscape-stored 10-bit HLG HEVC turned by a display matrix, read at odd
    crop offsets, comes back upright with the SDR colours it was made from."""
    upright = quadrants(96, 128)
    stored = write_hlg_video(tmp_path / "stored.mov", np.stack([np.rot90(upright, k=-1)] * 2))
    source = open_source(with_rotation(stored, tmp_path / "iphone.mov", 90))
    assert (source.width, source.height, source.transfer, source.deep) == (128, 96, "HLG", True)
    (_, image), _ = read(source, Region(33, 25, 62, 46))
    assert np.abs(interior(image).astype(int) - interior(quadrants(46, 62))).mean() <= HDR_ROUND_TRIP_TOLERANCE


def test_sdr_video_has_no_transfer(tmp_path):
    assert open_source(write_video(tmp_path / "numbered.mp4", numbered_frames(2))).transfer is None


def test_image_folder_in_name_order_with_exif_orientation(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    for k in (2, 0, 1):
        Image.fromarray(numbered_frames(3)[k]).save(folder / f"frame_{k:02d}.png")
    (folder / "notes.txt").write_text("not an image")
    source = open_source(folder)
    assert [(index, frame_number(image)) for index, image in read(source)] == [(0, 0), (1, 1), (2, 2)]

    upright = quadrants(96, 64)
    photos = tmp_path / "photos"
    photos.mkdir()
    exif = Image.Exif()
    exif[0x0112] = 6  # "turn 90 degrees clockwise to show"
    Image.fromarray(np.rot90(upright, k=1).copy()).save(photos / "a.jpg", quality=95, exif=exif)
    source = open_source(photos)
    assert (source.width, source.height) == (64, 96)
    ((_, image),) = read(source)
    assert np.abs(interior(image).astype(int) - interior(upright)).max() <= COMPRESSION_TOLERANCE


def test_image_folder_of_16_bit_greys(tmp_path):
    """A 16-bit grey PNG (PIL's mode I;16) reads as its top 8 bits, not clipped to white."""
    ramp = np.linspace(0, 65535, 48 * 64).reshape(48, 64).astype(np.uint16)
    Image.fromarray(ramp).save(tmp_path / "grey.png")
    ((_, image),) = read(open_source(tmp_path))
    np.testing.assert_array_equal(image, np.repeat((ramp >> 8).astype(np.uint8)[..., None], 3, axis=2))


def test_interlaced_video_comes_out_without_combing(tmp_path):
    """A bar moving right, its two fields half a frame apart (a camcorder's 1080i): read progressive, every
    row of the bar agrees; read as stored, the rows alternate between the fields' positions."""
    count, height, width = 4, 96, 128
    frames = np.full((count, height, width, 3), 40, np.uint8)
    for t in range(count):
        x = 20 + 16 * t
        frames[t, 0::2, x : x + 12] = 230  # top field
        frames[t, 1::2, x + 8 : x + 20] = 230  # bottom field, half a frame later
    path = write_encoded(tmp_path / "interlaced.mp4", frames, "libx264", "yuv420p", interlaced=True)
    source = open_source(path)
    assert source.interlaced
    images = np.stack([image for _, image in read(source)]).astype(float)
    assert len(images) == count
    inner = images[:, 8:-8]  # rows away from the top and bottom, which have one field each side
    combing = np.abs(np.diff(inner, axis=1)).mean()
    assert combing < 1.0, combing  # stored, the rows differ by about 24 grey levels on average


def test_image_folder_of_mixed_sizes_is_refused(tmp_path):
    for name, size in (("a.png", (64, 48)), ("b.png", (32, 48))):
        Image.new("RGB", size).save(tmp_path / name)
    with pytest.raises(PghmError, match="b.png: 32x48 pixels"):
        read(open_source(tmp_path))


def test_not_a_video(tmp_path):
    path = tmp_path / "notes.mp4"
    path.write_text("hello")
    with pytest.raises(PghmError, match="notes.mp4: not a readable video"):
        open_source(path)


def test_song_with_cover_art_has_no_video_stream(tmp_path):
    """ffmpeg lists an MP3's cover art as a video stream (an attached picture); it is not a video."""
    Image.new("RGB", (64, 48), (200, 30, 30)).save(tmp_path / "cover.png")
    song = tmp_path / "song.mp3"
    command = [ffmpeg(), "-v", "error", "-f", "lavfi", "-i", "sine=duration=1", "-i", str(tmp_path / "cover.png")]
    command += ["-map", "0", "-map", "1", "-c:v", "copy", "-disposition:v", "attached_pic", str(song)]
    subprocess.run(command, check=True)
    with pytest.raises(PghmError, match="song.mp3: has no video stream"):
        open_source(song)


def test_truncated_video(tmp_path):
    with pytest.raises(PghmError, match="cut.mp4: truncated or corrupt video"):
        read(open_source(truncated_video(tmp_path)))
