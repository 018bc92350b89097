"""The CPU thread policy of every command: one intra-op thread per core the process may use, and
threads that sleep when they wait, after a short spin when the cores are free.

A command's result must be a function of its inputs, seed and options. torch splits a reduction
(a convolution's weight gradient, a sum) over its intra-op threads and adds the partial sums in an
order set by their number, so two thread counts give results that differ in the last bits. The
count therefore comes from the cores this process may run on, its affinity mask (``taskset``,
cgroup cpusets), which does not change while the machine is busy, and never from how busy the
cores are at the moment.

torch's OpenMP threads meet at a barrier after each parallel loop. A thread that reaches it first
either spins or sleeps, and which serves depends on whether the cores are free:

- Idle, sleeping at once (``OMP_WAIT_POLICY=PASSIVE``) costs a wake-up at every barrier, and a
  network step is hundreds of short parallel loops: the fit's two threads did 1.35 cores' work. A
  spin of :data:`SPIN_COUNT` rounds first (about 30 microseconds) covers the gap between two loops:
  1.8-1.9 cores, stage 2 in 0.64-0.78 of the time.
- Beside another process that holds a core, the thread a barrier waits for is descheduled and
  spinning keeps the cores busier still: libgomp's default 3 ms spin made a step take 25 s instead
  of 1.3 at a load of 7-11, and even the short spin costs a quarter beside one busy loop
  (docs/lab/fit-speed.md, "The threads' wait").

So, before torch is imported, a thread sleeps at a barrier (any OpenMP runtime), after a short spin
(libgomp, torch's on Linux) only when the tasks the kernel has runnable at the start fit the
machine's cores beside this process's threads (:func:`cores_free`):

    OMP_WAIT_POLICY = PASSIVE
    GOMP_SPINCOUNT  = SPIN_COUNT       (only when the cores are free)

A user's ``OMP_WAIT_POLICY``, ``GOMP_SPINCOUNT`` or ``OMP_NUM_THREADS`` wins. The wait changes when
a thread runs, never what it adds up, so it may follow the load where the count may not: the
results are the same bits under any wait. The count in use is recorded in the avatar's metadata
and eval's report.
"""

from __future__ import annotations

import os
import time

WAIT_POLICY = "PASSIVE"
"""OpenMP's wait policy for torch's threads (see the module doc)."""
WAIT_VARIABLES = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")
"""The variables by which a user chooses how threads wait, instead of the policy."""
POLICY_VARIABLES = (*WAIT_VARIABLES, "OMP_NUM_THREADS")
"""Every variable by which a user overrides the thread policy: a child run as a user runs it has none."""
SPIN_COUNT = 3000
"""libgomp's spin rounds at a barrier before a waiting thread sleeps, on free cores: about 30
microseconds (libgomp counts some 100 rounds a microsecond), longer than the gap between two of a
step's parallel loops and a hundredth of libgomp's default (docs/lab/fit-speed.md, "The threads' wait")."""
RUN_QUEUE_SAMPLES = 5
RUN_QUEUE_INTERVAL_S = 0.002
"""Reads of the kernel's run queue by :func:`others_running`, and the seconds between them: 8 ms in all."""


def others_running(samples: int = RUN_QUEUE_SAMPLES, interval: float = RUN_QUEUE_INTERVAL_S) -> int:
    """The fewest tasks besides this one that the kernel had runnable at once over ``samples`` reads
    of /proc/stat's ``procs_running``, ``interval`` seconds apart: a busy process is in every read, a
    passing one rarely; 0 without /proc."""
    counts = []
    for sample in range(samples):
        try:
            with open("/proc/stat") as stat:
                line = next(line for line in stat if line.startswith("procs_running"))
        except (OSError, StopIteration):
            return 0
        counts.append(int(line.split()[1]) - 1)
        if sample + 1 < samples:
            time.sleep(interval)
    return max(min(counts), 0)


def cores_free(threads: int, others: int) -> bool:
    """Whether ``others`` runnable tasks and this process's ``threads`` fit the machine's cores."""
    return others + threads <= (os.cpu_count() or 1)


def set_wait_policy() -> None:
    """Make OpenMP threads sleep when they wait, after a :data:`SPIN_COUNT`-round spin if the cores are
    free (module doc), unless the user chose a policy or a spin count: call before torch is imported."""
    if any(name in os.environ for name in WAIT_VARIABLES):
        return
    os.environ["OMP_WAIT_POLICY"] = WAIT_POLICY
    if cores_free(_requested_threads() or usable_cores(), others_running()):
        os.environ["GOMP_SPINCOUNT"] = str(SPIN_COUNT)


def _requested_threads() -> int | None:
    """The thread count ``OMP_NUM_THREADS`` asks for (its first level), None if it names none."""
    first = os.environ.get("OMP_NUM_THREADS", "").split(",")[0].strip()
    return int(first) if first.isdigit() and int(first) > 0 else None


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
