"""The machine a benchmark records (:mod:`splitrender.evaluation.machine`)."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest
from splitrender import machine as m

INTEL = """processor\t: 0
vendor_id\t: GenuineIntel
cpu family\t: 6
model\t\t: 106
model name\t: Intel(R) Xeon(R) Platinum 8375C CPU @ 2.90GHz
stepping\t: 6

processor\t: 1
vendor_id\t: GenuineIntel
cpu family\t: 6
model\t\t: 106
model name\t: Intel(R) Xeon(R) Platinum 8375C CPU @ 2.90GHz
"""

# A virtual machine's name need not say the generation: the family and model numbers do.
AMD = """processor\t: 0
vendor_id\t: AuthenticAMD
cpu family\t: 25
model\t\t: 17
model name\t: AMD EPYC
"""

# An Arm board's: no model name, no family.
ARM = """processor\t: 0
BogoMIPS\t: 48.00
Features\t: fp asimd evtstrm crc32 cpuid
CPU implementer\t: 0x41
CPU part\t: 0xd08
"""


def test_the_processor_is_named_with_its_family_and_model() -> None:
    assert m.processor_name(INTEL) == (
        "Intel(R) Xeon(R) Platinum 8375C CPU @ 2.90GHz (family 6, model 106)"
    )
    assert m.processor_name(AMD) == "AMD EPYC (family 25, model 17)"


def test_only_the_first_processor_is_read() -> None:
    second = INTEL.replace("model name\t: Intel", "model name\t: Other", 1)
    other = INTEL.split("\n\n")[0] + "\n\n" + AMD
    assert m.processor_name(second).startswith("Other")
    assert m.processor_name(other).startswith("Intel(R) Xeon(R)")


def test_without_a_model_name_the_platform_names_it(monkeypatch) -> None:
    monkeypatch.setattr(platform, "processor", lambda: "")
    monkeypatch.setattr(platform, "machine", lambda: "aarch64")
    assert m.processor_name(ARM) == "aarch64"
    # Family and model only where both are numbers.
    assert m.processor_name("cpu family\t: 6\nmodel\t\t: x\n") == "aarch64"
    monkeypatch.setattr(platform, "machine", lambda: "")
    assert m.processor_name("") == "unknown"
    assert m.processor_name("garbage without colons\n\x00\xff") == "unknown"


def test_an_unreadable_cpuinfo_names_the_platform(monkeypatch, tmp_path: Path) -> None:
    monkeypatch.setattr(m, "CPUINFO", tmp_path / "absent")
    monkeypatch.setattr(platform, "processor", lambda: "  Some   CPU ")
    assert m.processor_name() == "Some CPU"


def test_describe() -> None:
    assert m.Machine("AMD EPYC (family 25, model 17)", 2, "avx512").describe() == (
        "AMD EPYC (family 25, model 17), 2 CPUs, CPU row loops AVX-512"
    )
    assert m.Machine("x", 1, "baseline").describe() == "x, 1 CPU, CPU row loops baseline"


def test_a_result_without_its_machine_describes_none() -> None:
    # What the text reports and the plot print: nothing for a result made by hand.
    assert m.describe_recorded("", 0, "") is None
    assert m.describe_recorded("Xeon", 2, "avx2") == m.Machine("Xeon", 2, "avx2").describe()


def test_this_machine_counts_the_cpus_the_process_may_use() -> None:
    here = m.this_machine()
    assert here.processor and here.simd in m.SIMD_NAMES
    if hasattr(os, "sched_getaffinity"):
        assert here.cpus == len(os.sched_getaffinity(0))
    else:
        assert here.cpus == os.cpu_count()


@pytest.mark.parametrize("tier", ["baseline", "avx2"])
def test_the_row_loops_tier_follows_reproj_simd(tier: str) -> None:
    # A cap the processor has is what the kernels run with; the baseline is always there.
    code = "from splitrender.machine import this_machine; print(this_machine().simd)"
    env = {**os.environ, "REPROJ_SIMD": tier}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         timeout=60, check=True).stdout.strip()
    uncapped = m.this_machine().simd
    order = list(m.SIMD_NAMES)[::-1]  # baseline, avx2, avx512
    assert out == min(tier, uncapped, key=order.index)


# /proc/stat's first lines on a 2-CPU VM whose host took 300 ticks: user nice system idle
# iowait irq softirq steal guest guest_nice.
STAT = """cpu  1000 10 200 5000 40 0 30 300 70 5
cpu0 500 5 100 2500 20 0 15 150 35 2
cpu1 500 5 100 2500 20 0 15 150 35 3
intr 12345 0 0
"""


def test_cpu_times_are_the_first_eight_columns_and_steal_the_eighth() -> None:
    # The guest columns are already inside user and nice: not counted twice.
    assert m.cpu_times(STAT) == m.CpuTimes(total=1000 + 10 + 200 + 5000 + 40 + 0 + 30 + 300,
                                           steal=300)


@pytest.mark.parametrize(
    "text",
    [
        "cpu  1000 10 200 5000 40 0 30\n",  # a kernel without the steal column
        "cpu  1000 10 200 5000 40 0 30 x 0 0\n",  # not a number
        "cpu  1000 10 200 5000 40 0 30 -3 0 0\n",  # negative
        "cpu  1000 10 200 5000 40 0 30 \u00b2 0 0\n",  # a digit to str.isdigit, not to int
        "cpu0 1000 10 200 5000 40 0 30 300 0 0\n",  # one CPU's line only
        "",
    ],
)
def test_cpu_times_without_a_whole_cpu_line_are_none(text: str) -> None:
    assert m.cpu_times(text) is None


def test_cpu_times_without_proc_stat_are_none(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(m, "PROC_STAT", tmp_path / "absent")
    assert m.cpu_times() is None


@pytest.mark.skipif(not Path("/proc/stat").exists(), reason="no /proc/stat on this platform")
def test_this_machine_counts_its_cpu_time() -> None:
    before = m.cpu_times()
    assert before is not None and before.total > 0 and 0 <= before.steal <= before.total


def test_steal_share_is_the_hosts_part_of_the_interval() -> None:
    assert m.steal_share(m.CpuTimes(1000, 100), m.CpuTimes(1400, 200)) == 0.25
    assert m.steal_share(m.CpuTimes(1000, 100), m.CpuTimes(1400, 100)) == 0.0


@pytest.mark.parametrize(
    ("before", "after"),
    [
        (None, m.CpuTimes(1400, 200)),
        (m.CpuTimes(1000, 100), None),
        (m.CpuTimes(1000, 100), m.CpuTimes(1000, 100)),  # no tick between them
        (m.CpuTimes(1000, 100), m.CpuTimes(900, 100)),  # counters went back (another boot)
        (m.CpuTimes(1000, 100), m.CpuTimes(1100, 50)),
        (m.CpuTimes(1000, 100), m.CpuTimes(1100, 300)),  # more stolen than passed
    ],
)
def test_steal_share_without_an_interval_is_none(before, after) -> None:
    assert m.steal_share(before, after) is None


def test_a_note_says_when_the_host_took_5_percent_or_more() -> None:
    assert m.steal_note([None, 4.99, 0.0], "it ran") is None
    assert m.steal_note([], "it ran") is None
    note = m.steal_note([None, 1.0, m.STEAL_NOTE_PCT], "it ran")
    assert note == (
        "note: the virtual machine's host took 5 % or more of the CPU time while it ran "
        "(steal): the figures include its time; run again when it takes none"
    )
