"""Where a fit's time goes: wall and CPU seconds per phase and part, opt-in (``pghm fit --profile``).

Every moment between :func:`profiled`'s start and end is charged to exactly one (phase, part)
pair, the innermost one open, so the parts of the table sum to the total by construction:

    total = sum over phases p, parts q of  t(p, q)

Phases are the fit's stretches (setup, stage 1, early settling, stage 2, pose settling, held-out
poses, save); parts are what a step does (:data:`PARTS`). The backward pass is one call into
autograd; hooks on the renders and on the Gaussians it splats (:func:`mark_backward`) switch the
part as the gradient crosses them, splitting it into the losses', the splatter's and the network's
backward. CPU time is the whole process's (every intra-op thread, spinning included), so CPU / wall
above 1 is threads at work or waiting actively. When no profile is active every hook is a no-op
costing one global lookup.
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from collections import defaultdict
from collections.abc import Iterator

import torch
from torch import Tensor

DATA = "data"
"""Reading the images and masks, drawing backgrounds and compositing the targets on them."""
NETWORK_FORWARD = "network forward"
"""Pose corrections, skinning, the U-Net and the Gaussians built from its maps."""
SPLAT_FORWARD = "splat forward"
"""Rendering both sets of Gaussians and compositing the renders."""
LOSSES = "losses"
"""L1, SSIM, silhouette, pose prior and the logged metrics."""
LOSSES_BACKWARD = "losses backward"
SPLAT_BACKWARD = "splat backward"
NETWORK_BACKWARD = "network backward"
OPTIMISER = "optimiser"
"""Gradient clipping and the Adam update."""
GUARD = "guard"
"""The loop's finite checks and the parameter backups that undo a non-finite update."""
CHECKPOINT = "checkpoint"
OTHER = "other"
"""Everything not inside a part: set-up, batch planning, progress bars, logging."""
PARTS = (
    DATA,
    NETWORK_FORWARD,
    SPLAT_FORWARD,
    LOSSES,
    LOSSES_BACKWARD,
    SPLAT_BACKWARD,
    NETWORK_BACKWARD,
    OPTIMISER,
    GUARD,
    CHECKPOINT,
    OTHER,
)
SETUP = "setup"
"""The phase before the first step: data, prior, body geometry."""


class Profile:
    """Exclusive wall and CPU seconds per (phase, part); see the module doc."""

    def __init__(self) -> None:
        self.wall: dict[tuple[str, str], float] = defaultdict(float)
        self.cpu: dict[tuple[str, str], float] = defaultdict(float)
        self.phases: list[str] = [SETUP]
        self.parts: list[str] = [OTHER]
        self.load = [os.getloadavg()[0]]
        self.threads = torch.get_num_threads()
        self._wall_mark, self._cpu_mark = time.perf_counter(), time.process_time()
        self.started_wall, self.started_cpu = self._wall_mark, self._cpu_mark
        self.children_cpu = 0.0
        """CPU seconds of forked children (:meth:`add_cpu`), which this process's clock does not count."""
        self.thread = threading.get_ident()
        """The thread whose parts are charged; other threads' work (torch's intra-op threads) falls in
        the part this one is in, as the CPU clock is the whole process's."""

    def charge(self) -> None:
        """Charge the time since the last mark to the open (phase, part)."""
        wall, cpu = time.perf_counter(), time.process_time()
        key = (self.phases[-1], self.parts[-1])
        self.wall[key] += wall - self._wall_mark
        self.cpu[key] += cpu - self._cpu_mark
        self._wall_mark, self._cpu_mark = wall, cpu

    @contextlib.contextmanager
    def phase(self, name: str) -> Iterator[None]:
        self.charge()
        self.phases.append(name)
        try:
            yield
        finally:
            self.charge()
            self.phases.pop()

    @contextlib.contextmanager
    def part(self, name: str) -> Iterator[None]:
        self.charge()
        self.parts.append(name)
        try:
            yield
        finally:
            self.charge()
            self.parts.pop()

    def switch(self, name: str) -> None:
        """Replace the innermost open part (the backward pass's hooks)."""
        self.charge()
        self.parts[-1] = name

    def finish(self) -> None:
        self.charge()
        self.load.append(os.getloadavg()[0])

    def add_cpu(self, seconds: dict[tuple[str, str], float]) -> None:
        """Add a forked child's CPU seconds per (phase, part) (:func:`forked`); its wall time is this
        process's, spent beside it."""
        for key, value in seconds.items():
            self.cpu[key] += value
            self.wall[key] += 0.0  # the part is listed in the record even where only the child ran it
            self.children_cpu += value

    def totals(self) -> tuple[float, float]:
        """(wall, CPU) seconds from start to the last mark, forked children's CPU included."""
        return self._wall_mark - self.started_wall, self._cpu_mark - self.started_cpu + self.children_cpu

    def phase_names(self) -> list[str]:
        """The phases charged so far, in the order they began."""
        return list(dict.fromkeys(phase for phase, _ in self.wall))

    def record(self) -> dict:
        """JSON-ready: seconds per phase and part (wall and CPU), totals, threads, load averages."""
        wall, cpu = self.totals()
        phases = self.phase_names()
        return {
            "wall_s": round(wall, 3),
            "cpu_s": round(cpu, 3),
            "threads": self.threads,
            "load_average": [round(value, 2) for value in self.load],
            "phases": {
                phase: {
                    part: {"wall_s": round(self.wall[phase, part], 3), "cpu_s": round(self.cpu[phase, part], 3)}
                    for part in PARTS
                    if (phase, part) in self.wall
                }
                for phase in phases
            },
        }

    def table(self) -> str:
        """Wall seconds per part (rows) and phase (columns), with the total wall and CPU per part."""
        phases = self.phase_names()
        header = ["part", *phases, "wall", "cpu"]
        rows = []
        for part in PARTS:
            cells = [self.wall.get((phase, part), 0.0) for phase in phases]
            cpu = sum(self.cpu.get((phase, part), 0.0) for phase in phases)
            rows.append([part, *(f"{c:.1f}" for c in cells), f"{sum(cells):.1f}", f"{cpu:.1f}"])
        wall, cpu = self.totals()
        per_phase = [sum(self.wall.get((phase, part), 0.0) for part in PARTS) for phase in phases]
        rows.append(["total", *(f"{c:.1f}" for c in per_phase), f"{wall:.1f}", f"{cpu:.1f}"])
        lines = [header, *rows]
        widths = [max(len(line[i]) for line in lines) for i in range(len(header))]

        def aligned(line: list[str]) -> str:
            cells = zip(line, widths)
            return "  ".join(cell.rjust(width) if i else cell.ljust(width) for i, (cell, width) in enumerate(cells))

        return "\n".join(aligned(line) for line in lines)


_ACTIVE: Profile | None = None
_NOTHING = contextlib.nullcontext()


@contextlib.contextmanager
def profiled() -> Iterator[Profile]:
    """Profile what runs inside: the parts and phases the fit marks are charged to the yielded profile."""
    global _ACTIVE
    if _ACTIVE is not None:
        raise RuntimeError("a profile is already active")
    _ACTIVE = Profile()
    try:
        yield _ACTIVE
    finally:
        _ACTIVE.finish()
        _ACTIVE = None


@contextlib.contextmanager
def forked() -> Iterator[Profile | None]:
    """In a child forked while a profile was active: a fresh profile of the child's own seconds,
    charged to the phase the parent was in (its copy of the parent's profile set aside; the parent
    adds the child's CPU with :meth:`Profile.add_cpu`); None, and nothing charged, when none was."""
    global _ACTIVE
    inherited = _ACTIVE
    if inherited is None:
        yield None
        return
    _ACTIVE = Profile()
    _ACTIVE.phases = [inherited.phases[-1]]
    try:
        yield _ACTIVE
    finally:
        _ACTIVE.charge()
        _ACTIVE = inherited


def add_cpu(seconds: dict[tuple[str, str], float]) -> None:
    """:meth:`Profile.add_cpu` on the active profile (nothing when none is)."""
    active = _active()
    if active is not None:
        active.add_cpu(seconds)


def _active() -> Profile | None:
    """The active profile when this thread is the one it charges, else None."""
    active = _ACTIVE
    return active if active is not None and active.thread == threading.get_ident() else None


def part(name: str) -> contextlib.AbstractContextManager:
    """Charge the time inside to ``name`` of the active profile (nothing when none is)."""
    active = _active()
    return active.part(name) if active is not None else _NOTHING


def phase(name: str) -> contextlib.AbstractContextManager:
    """Charge the time inside to phase ``name`` of the active profile (nothing when none is)."""
    active = _active()
    return active.phase(name) if active is not None else _NOTHING


def mark_backward(renders: list[Tensor], gaussians: list[Tensor]) -> None:
    """Split the backward pass at the renders and at the Gaussians splatted into them: gradients
    reaching ``renders`` start the splatter's backward, gradients reaching ``gaussians`` the network's."""
    profile = _active()
    if profile is None or not torch.is_grad_enabled():
        return
    for tensors, name in ((renders, SPLAT_BACKWARD), (gaussians, NETWORK_BACKWARD)):
        for tensor in tensors:
            if tensor.requires_grad:
                tensor.register_hook(lambda grad, name=name: profile.switch(name))
