"""The avatar as one web page: baked in a motion (:mod:`pghm.web.bake`), written as one
self-contained HTML file (:mod:`pghm.web.page`), played by ``player.js`` in any WebGL2 browser."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from pghm.web.bake import BakeConfig, BakedMotion, bake_motion

DEFAULT_MOTION = "walk"
"""The motion a page plays when none is given."""


@dataclass(frozen=True)
class WebExport:
    """What :func:`export_web` wrote: the file, its size, and what the bake kept."""

    path: Path
    bytes: int
    baked: BakedMotion


def export_web(
    avatar_path: str,
    motion_source: str = DEFAULT_MOTION,
    out: str = "avatar.html",
    identity: int = 0,
    body_model_path: str | None = None,
    device: torch.device | str = "cpu",
    config: BakeConfig | None = None,
) -> WebExport:
    """Write ``out``, a page playing identity ``identity`` of ``avatar_path`` in ``motion_source``
    (what ``pghm render --motion`` takes); the network runs on ``device``."""
    from pghm.io.atomic import atomic_write_bytes
    from pghm.io.avatar import load_avatar
    from pghm.motion.open_motion import open_motion
    from pghm.render.driver import AvatarDriver
    from pghm.web.page import page_html

    avatar = load_avatar(avatar_path).to(device)
    avatar.check_identity(identity)
    driver = AvatarDriver(avatar, identity, body_model_path)
    motion = open_motion(motion_source, driver.body, driver.geometry.shape.cpu(), avatar.pose_track)
    baked = bake_motion(driver, motion, config)
    html = page_html(baked, Path(avatar_path).stem).encode("utf-8")
    atomic_write_bytes(out, html)
    return WebExport(Path(out), len(html), baked)
