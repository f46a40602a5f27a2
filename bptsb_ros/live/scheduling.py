"""How a live node's threads are scheduled, ROS-free: under SCHED_FIFO (``rt_priority``) and on which CPUs
(``cpus``, in ``taskset -c`` form). ``body_sim``, the brains and the bench's paced anchor call these once, before
their loop; Linux only (elsewhere each says why not, in one line).
"""

from __future__ import annotations

from bptsb_ros.interface.params import ParameterError


def set_fifo_priority_of_other_threads(priority: int) -> int:
    """Put every other thread of this process (the middleware's: a step that publishes waits on locks they hold,
    so at the normal scheduler one of them preempted by another process stalls the step) under SCHED_FIFO at
    ``priority`` (one below the stepping thread's, which then preempts them); returns how many took it (Linux: the
    threads in ``/proc/self/task``)."""
    import os
    import threading

    me, done = threading.get_native_id(), 0
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        return 0
    for tid in tids:
        if tid == me:
            continue
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
            done += 1
        except OSError:  # gone meanwhile, or not allowed
            continue
    return done


#: the largest CPU number a ``cpus`` parameter may name (glibc's CPU_SETSIZE − 1)
MAX_CPU = 1023


def parse_cpus(text: str, name: str = "parameter 'cpus'") -> frozenset[int]:
    """The CPUs of a ``cpus`` parameter, written as ``taskset -c`` lists them: numbers and ranges separated by
    commas (``'1'``, ``'0,2'``, ``'0-3'``); empty (or blank): none. Raises ParameterError naming the bad part
    (after ``name``, what the text is)."""
    cpus: set[int] = set()
    for part in (p.strip() for p in text.split(",")):
        if not part and not text.strip():
            continue
        first, dash, last = part.partition("-")
        if not first.strip().isdecimal() or (dash and not last.strip().isdecimal()):
            raise ParameterError(f"{name}: {part!r} is not a CPU number or a range of them (taskset -c "
                                 "form: '1', '0,2', '0-3')")
        lo, hi = int(first), int(last) if dash else int(first)
        if hi < lo:
            raise ParameterError(f"{name}: the range {part!r} runs backwards")
        if hi > MAX_CPU:
            raise ParameterError(f"{name}: CPU {hi} is beyond {MAX_CPU}, the largest a CPU set holds")
        cpus.update(range(lo, hi + 1))
    return frozenset(cpus)


def cpus_text(cpus: frozenset[int]) -> str:
    """``cpus`` as plain comma-separated numbers, ascending (what ROS reads back as written: no leading zeros)."""
    return ",".join(map(str, sorted(cpus)))


def pin_threads(cpus: frozenset[int]) -> str:
    """Run every thread of this process on ``cpus`` (Linux: each thread in ``/proc/self/task``; threads made later
    inherit it from the thread that makes them); '' when done, else why not (one line): a CPU this process may not
    use, or threads that refused (the calling thread, or the list of threads unreadable, counts as not done). The
    body and the brains it waits for on one core: docs/ros/timing.md has what that measured."""
    import os

    if not hasattr(os, "sched_setaffinity"):
        return "this platform has no sched_setaffinity"
    allowed = os.sched_getaffinity(0)
    outside = sorted(cpus - allowed)
    if outside:
        return f"CPU(s) {', '.join(map(str, outside))} not available to this process (it may use " \
               f"{', '.join(map(str, sorted(allowed)))})"
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError as err:
        return f"the threads of this process cannot be listed ({err.strerror or err})"
    refused = 0
    for tid in tids:
        try:
            os.sched_setaffinity(tid, cpus)
        except ProcessLookupError:  # ended meanwhile
            continue
        except OSError:
            refused += 1
    return f"{refused} of {len(tids)} threads refused the CPU set" if refused else ""


def set_fifo_priority(priority: int) -> str:
    """Put the calling thread under SCHED_FIFO at ``priority`` (1-99); '' when done, else why not (one line)."""
    import os

    if not hasattr(os, "sched_setscheduler"):
        return "this platform has no sched_setscheduler"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as err:
        return f"SCHED_FIFO priority {priority} refused ({err.strerror or err}; needs CAP_SYS_NICE or root)"
    return ""


def set_fifo_priority_of_process(priority: int) -> tuple[str, int]:
    """The calling thread (the one that steps or answers) under SCHED_FIFO at ``priority`` and every other thread of
    this process one below (:func:`set_fifo_priority_of_other_threads`), as ``body_sim``, the brains and the bench's
    paced anchor run; returns ('' or why the priority was refused, how many other threads took ``priority`` − 1).
    Nothing changes where it is refused."""
    problem = set_fifo_priority(priority)
    return problem, 0 if problem else set_fifo_priority_of_other_threads(max(1, priority - 1))
