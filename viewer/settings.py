"""The viewer's display settings, HUD numbers and layout constants (shared by the state and the UI)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pghm.render import GaussianSet

ASSETS = Path(__file__).resolve().parent.parent / "assets"
"""What the repository ships: the trained avatars and prior, and real motion-capture clips."""
DEFAULT_AVATAR = ASSETS / "real_avatar.pt"
"""What ``pghm-view`` opens without an argument: a real person's avatar, made from a video by
``pghm capture`` and ``pghm fit`` with their defaults (assets/SOURCE.md)."""
SYNTHETIC_AVATAR = ASSETS / "avatar.pt"
"""The held-out synthetic subject personalised from the prior: its ground truth is known."""
SHIPPED_MOTIONS = ASSETS / "motion"
"""Real motion-capture clips (BVH); the motion browser starts here."""
WINDOW_SIZE = (1280, 800)
"""Default window size, screen pixels."""
PANEL_WIDTH = 360
"""Width of the control panel on the window's left; the scene fills the rest."""
BACKFACE_DEGREES = 17.5
"""The display option's back-face culling keeps a Gaussian unless its normal is more than 90 + this
degrees from the direction to the camera (n . v < -0.30, :func:`pghm.gl.cull.facing`): Gaussians
near the silhouette (n . v ~ 0) stay, because their blobs still show."""
SCALE_RANGE = (0.1, 4.0)
"""Point-size modifier range (multiplies every Gaussian's scale)."""
RENDER_SCALES = (1.0, 0.75, 0.5)
"""Internal resolutions offered (fraction of the viewport; the image is stretched bilinearly)."""


@dataclass
class DisplaySettings:
    """What is drawn and how.

    The last two are approximations, off by default (docs/viewer.md has their cost and error).
    """

    gaussians: GaussianSet = "dynamic"
    """The paper's dynamic set (I_d) or static set (I_s)."""
    view_dependent: bool = True
    """Include the view-dependent colour V_c^o (dynamic set only)."""
    scale_multiplier: float = 1.0
    """Point-size modifier: every scale times this."""
    background: tuple[float, float, float] = (0.16, 0.17, 0.19)
    """RGB behind the avatar."""
    show_centres: bool = False
    """Gaussian centres as points."""
    show_mesh: bool = False
    """Posed body mesh as lines."""
    follow: bool = True
    """Aim the camera at the root as the motion moves it."""
    render_scale: float = 1.0
    """Approximation: draw the sprites at this fraction of the viewport and stretch."""
    cull_backfacing: bool = False
    """Approximation: skip Gaussians whose posed normal faces away from the camera."""


@dataclass
class HudStats:
    """Numbers for the HUD (milliseconds unless stated): each stage's last run, this frame's fps."""

    fps: float = 0.0
    frame_ms: float = 0.0
    model_ms: float = 0.0
    skinning_ms: float = 0.0
    sort_ms: float = 0.0
    upload_ms: float = 0.0
    draw_ms: float = 0.0
    gaussians: int = 0
    drawn: int = 0
    """Gaussians the last sprite pass drew (fewer than ``gaussians`` with back-face culling)."""
    scene_redrawn: bool = False
    internal_size: tuple[int, int] = (0, 0)
    """Pixels the sprites were drawn at (below the viewport while the view moves)."""
    moving: bool = False
    """The view or the pose is moving: the frame is approximate (dynamic resolution)."""
    pending: bool = False
    """The model worker has not yet delivered what the state names: the last Gaussians are shown."""
    prefetching: bool = False
    """The model worker is evaluating clip frames into the cache."""
    cache_frames: int = 0
    cache_mb: float = 0.0
    cache_budget_mb: float = 0.0
