"""The CPU thread policy of every command: threads that sleep when they wait, and no more of them
than there are free cores.

torch runs an operator's work on OpenMP threads that meet at a barrier after each parallel loop.
By default a thread that reaches the barrier first spins, burning its core, for a while before it
sleeps; when another process holds the other core, the thread it waits for is descheduled and
the spinning one keeps the cores busier still, so a step beside one busy process can take several
times longer than twice its idle time (docs/training.md, "Speed"). So, before torch is imported:

    OMP_WAIT_POLICY = PASSIVE          (libgomp: a waiting thread sleeps at once)

and, once it is, torch's intra-op threads are :func:`intra_op_threads` of the cores and the
one-minute load average the command starts under. A user's ``OMP_WAIT_POLICY`` or
``OMP_NUM_THREADS`` wins over both.
"""

from __future__ import annotations

import os

WAIT_POLICY = "PASSIVE"
"""OpenMP's wait policy for torch's threads (see the module doc)."""
BUSY_CORE_LOAD = 0.5
"""Load average (runnable processes) from which a core counts as busy: a load of 0.5 to 1.5 takes
one core, 1.5 to 2.5 two, and so on (other processes' work, as the command starts before its own)."""


def intra_op_threads(cores: int, load: float) -> int:
    """Threads for torch's operators on ``cores`` cores with a one-minute load average ``load``:
    one per core that other processes leave free, at least one:

        threads = clamp(cores - floor(load + 1 - BUSY_CORE_LOAD), 1, cores).
    """
    busy = max(0, int(load + 1 - BUSY_CORE_LOAD))
    return max(1, min(cores, cores - busy))


def set_wait_policy() -> None:
    """Make OpenMP threads sleep when they wait, unless the user chose a policy: call before torch is imported."""
    os.environ.setdefault("OMP_WAIT_POLICY", WAIT_POLICY)


def _cores() -> int:
    """The cores this process may run on (its affinity mask: ``taskset`` counts)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def set_threads() -> int:
    """Set torch's intra-op threads by :func:`intra_op_threads` (unless ``OMP_NUM_THREADS`` is set); returns them."""
    import torch

    if os.environ.get("OMP_NUM_THREADS"):
        return torch.get_num_threads()
    try:
        load = os.getloadavg()[0]
    except OSError:  # no load average (not Linux or BSD): assume idle cores
        load = 0.0
    threads = intra_op_threads(_cores(), load)
    torch.set_num_threads(threads)
    return threads
