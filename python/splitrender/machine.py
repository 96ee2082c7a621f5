"""The machine a benchmark ran on, as its results record it.

A time means little without the processor it was measured on: the same build of ``ours``
took 10.5-13 ms per 1280×720 frame on one cloud host's Intel Xeon and 15-26 ms on another's
AMD EPYC (docs/performance.md, "Where it stands"), and a virtual machine's model name alone
need not say which generation it is ("AMD EPYC"). So ``splitrender bench`` and ``splitrender
bench --realtime`` print and record (and ``splitrender connect``'s report.json records) the
processor (with its x86 family and model numbers, which do), the CPUs this process may run
on, and the instruction set the CPU kernels' row loops use (``REPROJ_SIMD`` caps it; every
tier gives the same bytes, only the time differs). :func:`usable_cpus` is also what the
real-time report's CPU utilisation is a share of, so the module sits below the client and
the evaluation, which both use it.

A virtual machine's processor is also shared: while the host runs another guest on the cores
under this one's CPUs, the time is this machine's "steal" (Linux counts it in ``/proc/stat``).
On the project's 2-core VM it reached a quarter of the CPU time for minutes at a time, and the
real-time loop's deadline misses went with it (docs/realtime.md, "Time the host took"). So the
benches also record the share of the machine's CPU time the host took while they timed
(:func:`cpu_times`, :func:`steal_share`): a slow run whose host took 20 % says so itself. Over
a whole run, not per display frame: the kernel counts it in ticks (``USER_HZ``, 10 ms here),
longer than a frame at 120 Hz, so a frame's share would read 0 or a whole tick.
"""

from __future__ import annotations

import os
import platform
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "SIMD_NAMES", "STEAL_NOTE_PCT", "CpuTimes", "Machine", "cpu_times", "describe_recorded",
    "host_busy", "processor_name", "steal_note", "steal_share", "this_machine", "usable_cpus",
]

#: The row loops' instruction sets (``_native.simd_tier``) as people write them.
SIMD_NAMES = {"avx512": "AVX-512", "avx2": "AVX2", "baseline": "baseline"}

#: Where Linux describes the processors.
CPUINFO = Path("/proc/cpuinfo")
#: Where Linux counts the time its CPUs spent in each state.
PROC_STAT = Path("/proc/stat")
#: The host's share of the CPU time (per cent) from which a bench's text warns that its times
#: include the host's: on the project's VM, real-time runs of 10 s at 640×360 whose host took
#: 5-8 % missed 12-33 deadlines each, those whose host took under 0.5 % 0-3 (docs/realtime.md,
#: "Time the host took").
STEAL_NOTE_PCT = 5.0


@dataclass(frozen=True)
class Machine:
    """What :func:`this_machine` found: ``processor`` in words, ``cpus`` the logical CPUs this
    process may run on, ``simd`` the instruction set of the CPU kernels' row loops (a key of
    :data:`SIMD_NAMES`)."""

    processor: str
    cpus: int
    simd: str

    def describe(self) -> str:
        """One line: ``AMD EPYC (family 25, model 17), 2 CPUs, CPU row loops AVX-512``."""
        plural = "s" * (self.cpus != 1)
        simd = SIMD_NAMES.get(self.simd, self.simd)
        return f"{self.processor}, {self.cpus} CPU{plural}, CPU row loops {simd}"


def describe_recorded(processor: str, cpus: int, simd: str) -> str | None:
    """:meth:`Machine.describe` of the machine a result recorded, or ``None`` where it recorded
    none (a result made by hand, whose ``processor`` is empty)."""
    return Machine(processor, cpus, simd).describe() if processor else None


def processor_name(cpuinfo: str | None = None) -> str:
    """The processor in words, from ``cpuinfo`` (the text of ``/proc/cpuinfo``; read here
    when ``None``) where it names one, else what :mod:`platform` says, else ``"unknown"``.
    On x86 the family and model numbers follow the name, as ``(family 25, model 17)``."""
    if cpuinfo is None:
        try:
            cpuinfo = CPUINFO.read_text(errors="replace")
        except OSError:
            cpuinfo = ""
    # The first processor's fields (every logical CPU repeats them); a line without a colon,
    # or a value that is empty, names nothing.
    fields: dict[str, str] = {}
    for line in cpuinfo.splitlines():
        if not line.strip():
            if fields:
                break
            continue
        key, colon, value = line.partition(":")
        if colon and value.strip():
            fields.setdefault(key.strip().lower(), " ".join(value.split()))
    name = (
        fields.get("model name") or fields.get("hardware") or fields.get("cpu model")
        or " ".join(platform.processor().split()) or platform.machine() or "unknown"
    )
    family, model = fields.get("cpu family"), fields.get("model")
    if family is not None and model is not None and family.isdigit() and model.isdigit():
        name += f" (family {family}, model {model})"
    return name


def usable_cpus() -> int:
    """The logical CPUs this process may run on (its affinity where the platform has one)."""
    affinity = getattr(os, "sched_getaffinity", None)
    if affinity is not None:
        try:
            return len(affinity(0))
        except OSError:
            pass
    return os.cpu_count() or 1


def this_machine() -> Machine:
    """The machine this process runs on (module docs)."""
    from splitrender._native import simd_tier

    return Machine(processor=processor_name(), cpus=usable_cpus(), simd=simd_tier())


@dataclass(frozen=True)
class CpuTimes:
    """The machine's CPU time since it booted, all its CPUs together, in the kernel's ticks
    (the first line of ``/proc/stat``): ``total`` in every state (idle included), ``steal``
    the part the hypervisor gave to something else while this machine's CPUs had work."""

    total: int
    steal: int


def cpu_times(stat: str | None = None) -> CpuTimes | None:
    """The machine's :class:`CpuTimes` from ``stat`` (the text of ``/proc/stat``; read here
    when ``None``), or ``None`` where there is none to read (not Linux) or its ``cpu`` line
    does not have the eight numbers ``user nice system idle iowait irq softirq steal``.

    The two ``guest`` columns after them are not added: the kernel counts a guest's time in
    ``user`` and ``nice`` already."""
    if stat is None:
        try:
            stat = PROC_STAT.read_text(errors="replace")
        except OSError:
            return None
    for line in stat.splitlines():
        fields = line.split()
        if not fields or fields[0] != "cpu":
            continue
        ticks = fields[1:9]
        if len(ticks) < 8 or not all(t.isascii() and t.isdigit() for t in ticks):
            return None
        counts = [int(t) for t in ticks]
        return CpuTimes(total=sum(counts), steal=counts[7])
    return None


def host_busy(pct: float | None) -> bool:
    """Whether the host took :data:`STEAL_NOTE_PCT` or more of the machine's CPU time
    (``pct``, per cent; ``None``: not counted, so not known to be busy)."""
    return pct is not None and pct >= STEAL_NOTE_PCT


def steal_note(pcts: Sequence[float | None], what: str) -> str | None:
    """A line for a bench's text where the host was busy (:func:`host_busy`) in any of
    ``pcts`` (per cent) while ``what`` ran, else ``None``."""
    if not any(host_busy(p) for p in pcts):
        return None
    return (
        f"note: the virtual machine's host took {STEAL_NOTE_PCT:g} % or more of the CPU time "
        f"while {what} (steal): the figures include its time; run again when it takes none"
    )


def steal_share(before: CpuTimes | None, after: CpuTimes | None) -> float | None:
    """The share (0-1) of the machine's CPU time between the readings ``before`` and
    ``after`` (:func:`cpu_times`) that its host took (steal), or ``None`` where either
    reading is missing or they do not describe an interval (no tick between them, or
    counters that went back)."""
    if before is None or after is None:
        return None
    total, steal = after.total - before.total, after.steal - before.steal
    if total <= 0 or not 0 <= steal <= total:
        return None
    return steal / total
