"""The CPU thread policy of every command: threads that sleep when they wait, and no more of them
than there are free cores.

torch runs an operator's work on OpenMP threads that meet at a barrier after each parallel loop.
By default a thread that reaches the barrier first spins, burning its core, for a while before it
sleeps; when another process holds the other core, the thread it waits for is descheduled and
the spinning one keeps the cores busier still, so a step beside one busy process can take several
times longer than twice its idle time (docs/training.md, "Speed"). So, before torch is imported:

    OMP_WAIT_POLICY = PASSIVE          (libgomp: a waiting thread sleeps at once)

and, once it is, torch's intra-op threads are :func:`intra_op_threads` of the cores and of how
busy other processes keep them as the command starts: their share of the command's cores over
:data:`SAMPLE_SECONDS` (``/proc/stat``), not the one-minute load average, which still counts a
process that ended a minute ago (a capture just before a fit). A user's ``OMP_WAIT_POLICY`` or
``OMP_NUM_THREADS`` wins over both.
"""

from __future__ import annotations

import os
import time

WAIT_POLICY = "PASSIVE"
"""OpenMP's wait policy for torch's threads (see the module doc)."""
BUSY_CORE_LOAD = 0.5
"""Busy cores (other processes' work) from which a core counts as taken: 0.5 to 1.5 take one core,
1.5 to 2.5 two, and so on."""
SAMPLE_SECONDS = 0.2
"""How long the cores' use is sampled before the command's own work starts (20 scheduler ticks per
core at Linux's 100 Hz: a busy fraction to 5 %)."""
STAT = "/proc/stat"
IDLE_FIELDS = (3, 4)
"""Of a ``cpuN`` line's tick counters (user nice system idle iowait irq softirq steal ...), the idle ones."""


def intra_op_threads(cores: int, load: float) -> int:
    """Threads for torch's operators on ``cores`` cores of which other processes keep ``load`` busy:
    one per core that other processes leave free, at least one:

        threads = clamp(cores - floor(load + 1 - BUSY_CORE_LOAD), 1, cores).
    """
    busy = max(0, int(load + 1 - BUSY_CORE_LOAD))
    return max(1, min(cores, cores - busy))


def set_wait_policy() -> None:
    """Make OpenMP threads sleep when they wait, unless the user chose a policy: call before torch is imported."""
    os.environ.setdefault("OMP_WAIT_POLICY", WAIT_POLICY)


def _cpus() -> set[int]:
    """The cores this process may run on (its affinity mask: ``taskset`` counts)."""
    try:
        return set(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return set(range(os.cpu_count() or 1))


def cpu_ticks(stat: str, cpus: set[int]) -> tuple[int, int]:
    """(busy, total) scheduler ticks summed over the ``cpuN`` lines of ``stat`` (/proc/stat's text)
    whose N is in ``cpus``."""
    busy = total = 0
    for line in stat.splitlines():
        name, *fields = line.split()
        if not (name.startswith("cpu") and name[3:].isdigit() and int(name[3:]) in cpus):
            continue
        ticks = [int(field) for field in fields[:8]]
        idle = sum(ticks[i] for i in IDLE_FIELDS)
        busy, total = busy + sum(ticks) - idle, total + sum(ticks)
    return busy, total


def busy_cores(before: tuple[int, int], after: tuple[int, int], cores: int) -> float:
    """Cores kept busy between two :func:`cpu_ticks` readings of ``cores`` cores (0 when no tick passed)."""
    busy, total = after[0] - before[0], after[1] - before[1]
    return cores * busy / total if total > 0 else 0.0


def current_load(cpus: set[int]) -> float:
    """Cores of ``cpus`` other processes keep busy now (sampled for SAMPLE_SECONDS while this one
    sleeps); the one-minute load average where there is no /proc/stat."""
    try:
        with open(STAT) as file:
            before = cpu_ticks(file.read(), cpus)
        time.sleep(SAMPLE_SECONDS)
        with open(STAT) as file:
            after = cpu_ticks(file.read(), cpus)
    except OSError:
        try:
            return os.getloadavg()[0]
        except OSError:  # neither (not Linux or BSD): assume idle cores
            return 0.0
    return busy_cores(before, after, len(cpus))


def set_threads() -> int:
    """Set torch's intra-op threads by :func:`intra_op_threads` (unless ``OMP_NUM_THREADS`` is set); returns them."""
    import torch

    if os.environ.get("OMP_NUM_THREADS"):
        return torch.get_num_threads()
    cpus = _cpus()
    # One core leaves nothing to decide: no need to sample its use.
    threads = intra_op_threads(len(cpus), current_load(cpus)) if len(cpus) > 1 else 1
    torch.set_num_threads(threads)
    return threads
