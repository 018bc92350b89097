"""Shared pieces of the stress suite: the outcome collector, a fast real-CLI runner, bad files.

Not a ``conftest.py``: the other tests ``from conftest import ...`` the top-level one, and a
second ``conftest`` module would shadow it.

**Collector.** Each case calls :func:`check` with what it tried, what the spec or the error
contract expects, what it observed, and whether that is right; the row is kept (pass or
FAIL) and the check asserted. When ``$PGHM_STRESS_RECORD`` names a file, every row is
written there as JSON at exit; ``pghm bench stress`` runs this suite that way and renders
the rows as docs/stress.md (totals) and docs/lab/stress-cases.md (every row), so the tables
are the suite's own record, not hand-written.

**CLI runner.** :func:`cli` runs ``pghm ARGS`` in a real child process (forked from a
server that has already imported pghm, see ``cli_server.py``) and returns its exit status,
stdout and stderr; :func:`one_error_line` holds a result to the error contract of
pghm/errors.py: exit status 2 and exactly one stderr line ``pghm: error: ...``.
"""

from __future__ import annotations

import atexit
import io
import json
import os
import subprocess
import sys
import threading
from dataclasses import asdict, dataclass
from pathlib import Path

import torch

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent

# ------------------------------------------------------------------------------ collector


@dataclass
class Row:
    """One stress case and its outcome."""

    area: str
    case: str
    expected: str
    observed: str
    passed: bool
    test: str


ROWS: list[Row] = []


def _current_test() -> str:
    return os.environ.get("PYTEST_CURRENT_TEST", "").split(" ")[0]


def check(area: str, case: str, expected: str, observed: str, ok: bool) -> None:
    """Record a case's outcome and assert it (the row says FAIL when the assertion fails)."""
    ROWS.append(Row(area, case, expected, observed, bool(ok), _current_test()))
    assert ok, f"[{area}] {case}: expected {expected}; observed {observed}"


def _write_record() -> None:
    target = os.environ.get("PGHM_STRESS_RECORD")
    if target:
        Path(target).write_text(json.dumps([asdict(row) for row in ROWS], indent=1) + "\n")


atexit.register(_write_record)

# ----------------------------------------------------------------------------- CLI runner


@dataclass
class CliResult:
    code: int
    stdout: str
    stderr: str

    @property
    def error_lines(self) -> list[str]:
        return [line for line in self.stderr.splitlines() if line.strip()]


class _Server:
    """The fork server process (one per test process, started on first use)."""

    def __init__(self) -> None:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.process = subprocess.Popen(
            [sys.executable, str(HERE / "cli_server.py")],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env=env,
            cwd=ROOT,
        )
        self.lock = threading.Lock()

    def run(self, argv: list[str], cwd: Path, env: dict[str, str]) -> CliResult:
        with self.lock:
            self.process.stdin.write(json.dumps({"argv": argv, "cwd": str(cwd), "env": env}) + "\n")
            self.process.stdin.flush()
            line = self.process.stdout.readline()
        if not line:
            raise RuntimeError(f"the CLI server died (exit {self.process.poll()})")
        reply = json.loads(line)
        return CliResult(reply["code"], reply["stdout"], reply["stderr"])

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.stdin.close()
            self.process.wait(timeout=30)


_server: _Server | None = None


def cli(*argv: object, cwd: Path | None = None, env: dict[str, str] | None = None) -> CliResult:
    """Run ``pghm ARGV`` in a child process (with ``env`` added to its environment); returns its
    exit status and output."""
    global _server
    if _server is None:
        _server = _Server()
        atexit.register(_server.close)
    return _server.run([str(a) for a in argv], cwd or ROOT, env or {})


def one_error_line(result: CliResult) -> tuple[bool, str]:
    """(the result keeps the error contract, what was observed): exit 2, one stderr line 'pghm: error: ...'."""
    lines = result.error_lines
    ok = result.code == 2 and len(lines) == 1 and lines[0].startswith("pghm: error: ")
    if ok:
        return True, f"exit 2: {lines[0][len('pghm: error: ') :]}"
    tail = " | ".join(lines[-3:])[-300:]
    return False, f"exit {result.code}, {len(lines)} stderr line(s): {tail}"


# ------------------------------------------------------------------------------ bad files


class RunsCode:
    """Unpickling this object would create ``marker`` (a stand-in for any code)."""

    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


UNSAFE_LOAD = "import sys, torch; torch.load(sys.argv[1], weights_only=False)"
"""What a careless reader does with an avatar file: a full unpickle."""
UNSAFE_LOAD_TIMEOUT = 120
"""Seconds for the child that loads unsafely (importing torch takes a few)."""


def unsafe_load_runs_code(path: Path, marker: Path) -> bool:
    """Whether a careless ``torch.load(path, weights_only=False)`` creates ``marker``: the positive
    control without which "the marker never appears" would prove nothing. The load runs in a child
    process, so what the pickle does stays there; the marker is removed afterwards."""
    command = [sys.executable, "-c", UNSAFE_LOAD, str(path)]
    subprocess.run(command, cwd=path.parent, capture_output=True, timeout=UNSAFE_LOAD_TIMEOUT)
    created = marker.exists()
    marker.unlink(missing_ok=True)
    return created


def bad_avatar_files(good: Path, directory: Path, marker: Path) -> dict[str, tuple[Path, str]]:
    """Every kind of bad avatar file, made from the valid ``good`` one: name -> (path, words the error names)."""
    from pghm.io.avatar import FORMAT_VERSION

    directory.mkdir(parents=True, exist_ok=True)
    data = good.read_bytes()
    payload = torch.load(good, weights_only=True)

    def saved(name: str, **changes) -> Path:
        changed = dict(payload)
        for key, value in changes.items():
            if value is KeyError:
                del changed[key]
            else:
                changed[key] = value
        path = directory / f"{name}.pt"
        buffer = io.BytesIO()
        torch.save(changed, buffer)
        path.write_bytes(buffer.getvalue())
        return path

    def raw(name: str, content: bytes) -> Path:
        path = directory / f"{name}.pt"
        path.write_bytes(content)
        return path

    latent = payload["latent"]
    return {
        "truncated (half the bytes)": (raw("truncated", data[: len(data) // 2]), "truncated or corrupted"),
        "random bytes": (raw("random", os.urandom(4096)), "avatar file"),
        "wrong version": (saved("version", version=FORMAT_VERSION + 98), "format version"),
        "missing key": (saved("missing", latent=KeyError), "missing keys: latent"),
        "pickle that runs code": (saved("code", metadata={"x": RunsCode(str(marker))}), "refusing to load"),
        "tensor of wrong shape": (saved("shape", latent=latent[:, :1]), "'latent' has shape"),
        "tensor of wrong dtype": (saved("dtype", latent=latent.long()), "dtype torch.int64"),
        "tensor with NaN": (saved("nan", latent=latent.clone().fill_(float("nan"))), "non-finite"),
    }


# ------------------------------------------------------------- two versions of each output

AVATAR_CONFIG = dict(
    uv_resolution=64,
    latent_channels=8,
    encoder_channels=(8, 12, 16, 24),
    decoder_channels=(16, 12, 8),
    condition_channels=(4, 4, 8, 8),
)
"""conftest.SMALL_MODEL's sizes (the child process of the kill test cannot import conftest)."""
PLY_GAUSSIANS = 200_000
"""50 MB of .ply: a save long enough (tens of ms) for a kill to land inside it."""
PNG_SIDE = 1024
"""A 1024 x 1024 noise PNG (3 MB, hardly compressible)."""


def output_versions(version: int) -> dict[str, tuple[callable, callable]]:
    """Version 0 or 1 of each output the kill test saves: name -> (save(path), content(path) == this version?)."""
    import numpy as np
    from PIL import Image

    from pghm.body import load_body
    from pghm.io.avatar import load_avatar, save_avatar
    from pghm.io.ply import read_ply, write_ply
    from pghm.model import ModelConfig
    from pghm.motion.motion import Motion
    from pghm.render import PngFileSink
    from viewer.demo import development_avatar

    generator = np.random.default_rng(version)
    avatar = development_avatar(ModelConfig(**AVATAR_CONFIG), seed=version)
    means = torch.from_numpy(generator.normal(size=(PLY_GAUSSIANS, 3)).astype(np.float32))
    scales = torch.full((PLY_GAUSSIANS,), 0.01 * (version + 1))
    colors = torch.rand(PLY_GAUSSIANS, 3, generator=torch.Generator().manual_seed(version))
    opacities = torch.full((PLY_GAUSSIANS,), 0.5)
    image = generator.integers(0, 256, (PNG_SIDE, PNG_SIDE, 3), dtype=np.uint8)
    body = load_body()
    motion = Motion(
        np.full((500, body.num_bones, 3), 0.1 * version, np.float32),
        np.zeros((500, 3), np.float32),
        30.0,
        "anny",
        list(body.bone_names),
        f"version {version}",
    )

    def png_save(path):
        PngFileSink(path).write(image)

    return {
        "avatar.pt": (
            lambda path: save_avatar(path, avatar),
            lambda path: torch.equal(load_avatar(path).latent, avatar.latent),
        ),
        "gaussians.ply": (
            lambda path: write_ply(path, means, scales, colors, opacities),
            lambda path: torch.equal(read_ply(path)[0], means),
        ),
        "frame.png": (png_save, lambda path: np.array_equal(np.asarray(Image.open(path).convert("RGB")), image)),
        "clip.npz": (
            lambda path: motion.save(path),
            lambda path: np.array_equal(Motion.load(path).rotations, motion.rotations),
        ),
    }


# ------------------------------------------------------------- the splatter's spec, brute force

THRESHOLD_BAND = 1e-4
"""Relative band around alpha = 1/255 where float32 and float64 may disagree on whether a pair
takes part (float32 alpha carries ~1e-6 relative error); such pixels are left out of image
comparisons (as in tests/test_splat.py)."""


def spec_image(means, scales, colors, opacities, camera, background, stride: int = 1):
    """rgb (H, W, 3), alpha, depth of the spec in pghm/splat/__init__.py, float64, one pixel plane
    per Gaussian (fine for a few Gaussians at any size), and the pixels at the 1/255 threshold.
    With ``stride`` > 1, only every stride-th row and column (for huge images)."""
    from pghm.splat.spec import ALPHA_MAX, ALPHA_MIN, COV_DILATION, FRUSTUM_CLAMP, NEAR_PLANE

    f64 = torch.float64
    fx, fy, cx, cy = (float(getattr(camera, name)) for name in ("fx", "fy", "cx", "cy"))
    width, height = camera.width, camera.height
    pose = camera.world_to_camera.detach().to(f64)
    t = means.detach().to(f64) @ pose[:3, :3].T + pose[:3, 3]
    background = torch.as_tensor(background, dtype=f64)
    columns = torch.arange(0, width, stride, dtype=f64)[None, :] + 0.5
    rows = torch.arange(0, height, stride, dtype=f64)[:, None] + 0.5
    shape = (rows.shape[0], columns.shape[1])
    transmittance = torch.ones(shape, dtype=f64)
    rgb = torch.zeros(*shape, 3, dtype=f64)
    depth = torch.zeros(shape, dtype=f64)
    ambiguous = torch.zeros(shape, dtype=torch.bool)
    for n in torch.sort(t[:, 2], stable=True).indices.tolist():
        x, y, z = t[n].tolist()
        if z <= NEAR_PLANE:
            continue
        u, v = fx * x / z + cx, fy * y / z + cy
        limit_x, limit_y = FRUSTUM_CLAMP * width / (2 * fx), FRUSTUM_CLAMP * height / (2 * fy)
        jx = min(max(x / z, -limit_x), limit_x)
        jy = min(max(y / z, -limit_y), limit_y)
        s2 = float(scales[n]) ** 2
        gx, gy = fx / z, fy / z
        sxx = s2 * gx * gx * (1 + jx * jx) + COV_DILATION
        sxy = s2 * gx * gy * jx * jy
        syy = s2 * gy * gy * (1 + jy * jy) + COV_DILATION
        det = sxx * syy - sxy * sxy
        a, b, c = syy / det, -sxy / det, sxx / det
        dx, dy = columns - u, rows - v
        raw = float(opacities[n]) * torch.exp(-0.5 * (a * dx * dx + 2 * b * dx * dy + c * dy * dy))
        ambiguous |= (raw - ALPHA_MIN).abs() <= THRESHOLD_BAND * ALPHA_MIN
        alpha = torch.where(raw >= ALPHA_MIN, raw.clamp(max=ALPHA_MAX), torch.zeros_like(raw))
        weight = alpha * transmittance
        rgb += weight[..., None] * colors[n].detach().to(f64)
        depth += weight * z
        transmittance = transmittance * (1 - alpha)
    rgb += transmittance[..., None] * background
    return rgb, 1 - transmittance, depth, ambiguous


def check_property(area: str, case: str, expected: str, run, describe) -> None:
    """Run a hypothesis property and record it: FAIL with the counterexample's message, or pass
    with ``describe()`` (how many examples, the largest deviation seen)."""
    try:
        run()
    except Exception as error:  # noqa: BLE001 - hypothesis re-raises the failing example's error
        message = str(error).strip().splitlines()
        check(area, case, expected, f"counterexample: {message[0][:200] if message else type(error).__name__}", False)
    check(area, case, expected, describe(), True)
