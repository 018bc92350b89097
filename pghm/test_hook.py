"""A test hook: Ctrl-C at a named point of a command, so interruption tests do not race the clock.

When the environment variable ``PGHM_TEST_INTERRUPT_AT`` equals a point's name, reaching
:func:`interrupt_point` sends this process SIGINT (what Ctrl-C in a terminal sends), so the
KeyboardInterrupt is raised right there. Unset (always, outside tests) it does nothing.

Points: ``startup`` (pghm.cli.main, before the subcommand modules and torch are imported),
``render-frame`` (pghm.render.job, after the first frame is written), ``synth-subjects``
(pghm.data.synth.generate, after the images are rendered, before the subjects' files are
written). tests/stress/test_adversarial.py uses each.
"""

from __future__ import annotations

import os
import signal

TEST_INTERRUPT_VARIABLE = "PGHM_TEST_INTERRUPT_AT"


def interrupt_point(name: str) -> None:
    """SIGINT to this process when ``$PGHM_TEST_INTERRUPT_AT`` is ``name`` (a test hook; see the module doc)."""
    if os.environ.get(TEST_INTERRUPT_VARIABLE) == name:
        os.kill(os.getpid(), signal.SIGINT)
