"""The CPU thread policy of every command: one intra-op thread per core the process may use, and
threads that sleep when they wait.

A command's result must be a function of its inputs, seed and options. torch splits a reduction
(a convolution's weight gradient, a sum) over its intra-op threads and adds the partial sums in an
order set by their number, so two thread counts give results that differ in the last bits. The
count therefore comes from the cores this process may run on, its affinity mask (``taskset``,
cgroup cpusets), which does not change while the machine is busy, and never from how busy the
cores are at the moment.

torch's OpenMP threads meet at a barrier after each parallel loop, and by default a thread that
reaches it first spins for a while, burning a core. Beside another process that holds a core, the
thread it waits for is descheduled and the spinning keeps the cores busier still: a step took 25 s
instead of 1.3 (docs/training.md, "Speed"). So, before torch is imported:

    OMP_WAIT_POLICY = PASSIVE          (libgomp: a waiting thread sleeps at once)

A user's ``OMP_WAIT_POLICY`` or ``OMP_NUM_THREADS`` wins over both. The count in use is recorded
in the avatar's metadata and eval's report.
"""

from __future__ import annotations

import os

WAIT_POLICY = "PASSIVE"
"""OpenMP's wait policy for torch's threads (see the module doc)."""


def set_wait_policy() -> None:
    """Make OpenMP threads sleep when they wait, unless the user chose a policy: call before torch is imported."""
    os.environ.setdefault("OMP_WAIT_POLICY", WAIT_POLICY)


def usable_cores() -> int:
    """The cores this process may run on: its affinity mask (``taskset`` and cpusets count), which
    other processes' load does not change."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def set_threads() -> int:
    """Set torch's intra-op threads to :func:`usable_cores` (unless ``OMP_NUM_THREADS`` is set); returns them."""
    import torch

    if os.environ.get("OMP_NUM_THREADS"):
        return torch.get_num_threads()
    threads = usable_cores()
    torch.set_num_threads(threads)
    return threads

