"""A test hook: lets tests inject faults (a Ctrl-C, a kill mid-save) into running commands.

Private: nothing outside the test suite sets its environment variables, and with them unset
every function here returns at once. Interruption and kill tests use it to choose the moment
they interrupt a command instead of racing the clock.

**Ctrl-C or SIGTERM at a named point.**
When the environment variable ``PGHM_TEST_INTERRUPT_AT`` equals a point's name, reaching
:func:`interrupt_point` sends this process SIGINT (what Ctrl-C in a terminal sends), so the
KeyboardInterrupt is raised right there; ``NAME:SIGTERM`` sends SIGTERM instead (what a
shutdown or a job scheduler sends). Unset (always, outside tests) it does nothing.

Points: ``startup`` (pghm.cli.main, before the subcommand modules and torch are imported),
``render-frame`` (pghm.render.job, after the first frame is written), ``synth-subjects``
(pghm.synth.generate, after the images are rendered, before the subjects' files are
written), ``train-step`` (pghm.train.loop, after each step and its checkpoint).
tests/stress/test_adversarial.py uses each.

**A pause inside a save, for kill -9 tests.** With ``PGHM_TEST_PAUSE_SAVE="POINT:N:NAME"`` and
``PGHM_TEST_PAUSE_MARKER=PATH``, the N-th time (1-based, per process) an atomic save
(:mod:`pghm.io.atomic`) to a file named NAME reaches POINT, the process creates PATH and sleeps
until it is killed. The points are the three states a save can be interrupted in:

* ``created``: the temporary file exists, empty; the destination is untouched;
* ``written``: the temporary file holds the whole new content, fsynced; not yet renamed;
* ``renamed``: the new content is under the destination's name (the save is complete).

tests/stress/test_nothing_lost.py kills writers and training runs at each.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path
from typing import Literal

TEST_INTERRUPT_VARIABLE = "PGHM_TEST_INTERRUPT_AT"


def interrupt_point(name: str) -> None:
    """SIGINT (or the signal named after a colon) to this process when ``$PGHM_TEST_INTERRUPT_AT``
    names ``name`` (a test hook; see the module doc)."""
    point, _, signal_name = os.environ.get(TEST_INTERRUPT_VARIABLE, "").partition(":")
    if point == name:
        os.kill(os.getpid(), signal.Signals[signal_name or "SIGINT"])


PAUSE_VARIABLE = "PGHM_TEST_PAUSE_SAVE"
"""``POINT:N:NAME``: pause at the N-th ``POINT`` of a save to a file named ``NAME``."""
PAUSE_MARKER_VARIABLE = "PGHM_TEST_PAUSE_MARKER"
"""The file created once the writer has paused (the test's cue to kill it)."""
SavePoint = Literal["created", "written", "renamed"]
_points_reached: dict[tuple[str, str], int] = {}
"""(point, file name) -> how many times this process has reached it."""


def save_point(point: SavePoint, path: Path) -> None:
    """Pause for good at this point of the save to ``path`` when ``$PGHM_TEST_PAUSE_SAVE`` asks for it
    (a test hook; see the module doc); return at once otherwise."""
    request = os.environ.get(PAUSE_VARIABLE)
    if request is None:
        return
    key = (point, path.name)
    _points_reached[key] = _points_reached.get(key, 0) + 1
    wanted_point, wanted_count, wanted_name = request.split(":", 2)
    if (wanted_point, int(wanted_count), wanted_name) != (point, _points_reached[key], path.name):
        return
    os.close(os.open(os.environ[PAUSE_MARKER_VARIABLE], os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
    while True:  # until the test's SIGKILL
        time.sleep(60)
