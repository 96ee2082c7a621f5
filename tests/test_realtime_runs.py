"""scripts/realtime_runs.py: late frames against the host's share over `bench --realtime` runs."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "realtime_runs.py"


@pytest.fixture(scope="module")
def script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("realtime_runs", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    # Registered first: its dataclass looks its module up by name.
    sys.modules["realtime_runs"] = module
    spec.loader.exec_module(module)
    return module


def write(tmp: Path, name: str, **fields: object) -> Path:
    d = {"frames": 1200, "deadline_misses": 0, "achieved_fps": 120.0, **fields}
    path = tmp / name
    path.write_text(json.dumps(d))
    return path


def test_runs_are_grouped_by_the_hosts_share_and_ranked(script, tmp_path, capsys) -> None:
    files = [
        write(tmp_path, "a.json", deadline_misses=0, host_steal_pct=0.0),
        write(tmp_path, "b.json", deadline_misses=3, host_steal_pct=2.0),
        write(tmp_path, "c.json", deadline_misses=20, host_steal_pct=7.0),
        write(tmp_path, "d.json", deadline_misses=90, host_steal_pct=30.0, frames=600),
        write(tmp_path, "e.json", deadline_misses=5),  # made before the share was recorded
    ]
    png = tmp_path / "plot.png"
    assert script.main([*map(str, files), "--plot", str(png)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[5].split() == ["e.json", "1200", "5", "n/a", "120.0"]
    assert out[7:] == [
        "host took 0-5 %: 2 runs, late frames 0-3 a run, 3 in 2400 frames, 1 run without one",
        "host took 5-15 %: 1 run, late frames 20-20 a run, 20 in 1200 frames, 0 runs without one",
        "host took 15 % or more: 1 run, late frames 90-90 a run, 90 in 600 frames, 0 runs "
        "without one",
        "Spearman's rho, late frames against the host's share: 1.00 over 4 runs",
    ]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_each_group_says_what_made_its_frames_late(script, tmp_path, capsys) -> None:
    def by(late_start: int, more_cpu: int, waited: int) -> dict[str, int]:
        return {"late_start": late_start, "more_cpu": more_cpu, "waited": waited}

    files = [
        write(tmp_path, "a.json", deadline_misses=3, host_steal_pct=1.0,
              deadline_misses_by_cause=by(0, 1, 2)),
        write(tmp_path, "b.json", deadline_misses=4, host_steal_pct=2.0,
              deadline_misses_by_cause=by(3, 0, 1)),
        write(tmp_path, "c.json", deadline_misses=9, host_steal_pct=8.0,
              deadline_misses_by_cause=by(5, 1, 3)),
        # Without its causes (made before they were recorded): its group says none.
        write(tmp_path, "d.json", deadline_misses=2, host_steal_pct=9.0),
    ]
    assert script.main(list(map(str, files))) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[6:9] == [
        "host took 0-5 %: 2 runs, late frames 3-4 a run, 7 in 2400 frames (3 started late, "
        "1 more CPU, 3 threads waited), 0 runs without one",
        "host took 5-15 %: 2 runs, late frames 2-9 a run, 11 in 2400 frames, 0 runs without one",
        "host took 15 % or more: no run",
    ]


def test_a_plot_that_cannot_be_written_is_refused(script, tmp_path, capsys) -> None:
    run = write(tmp_path, "a.json", host_steal_pct=1.0)
    assert script.main([str(run), "--plot", str(tmp_path / "absent" / "p.png")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("realtime_runs: error: --plot: cannot write the file") and "absent" in err
    assert not (tmp_path / "absent").exists()


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("not json", "not a readable JSON file"),
        ("[1, 2]", "expected the object"),
        ('{"frames": 10, "achieved_fps": 1.0}', "a number `deadline_misses`"),
        ('{"frames": true, "deadline_misses": 0, "achieved_fps": 1.0}', "a number `frames`"),
        ('{"frames": 10, "deadline_misses": 0, "achieved_fps": 1.0, "host_steal_pct": 140}',
         "is not a share in 0-100"),
        ('{"frames": 10, "deadline_misses": 11, "achieved_fps": 1.0}',
         "11 deadline misses of 10 frames"),
        ('{"frames": -1, "deadline_misses": -2, "achieved_fps": 1.0}',
         "-2 deadline misses of -1 frames"),
        ('{"frames": 10, "deadline_misses": 0, "achieved_fps": Infinity}',
         "`achieved_fps` inf is not a rate"),
        ('{"frames": 10, "deadline_misses": 0, "achieved_fps": NaN}',
         "`achieved_fps` nan is not a rate"),
        ('{"frames": 10, "deadline_misses": 0, "achieved_fps": -3}',
         "`achieved_fps` -3 is not a rate"),
        ('{"frames": 10, "deadline_misses": 1, "achieved_fps": 1.0, '
         '"deadline_misses_by_cause": [1]}', "`deadline_misses_by_cause` [1] is not counts"),
        ('{"frames": 10, "deadline_misses": 1, "achieved_fps": 1.0, '
         '"deadline_misses_by_cause": {"late_start": 1, "more_cpu": 0}}', "is not counts >= 0"),
        ('{"frames": 10, "deadline_misses": 1, "achieved_fps": 1.0, "deadline_misses_by_cause": '
         '{"late_start": 2, "more_cpu": -1, "waited": 0}}', "is not counts >= 0"),
        ('{"frames": 10, "deadline_misses": 1, "achieved_fps": 1.0, "deadline_misses_by_cause": '
         '{"late_start": true, "more_cpu": 0, "waited": 0}}', "is not counts >= 0"),
        ('{"frames": 10, "deadline_misses": 3, "achieved_fps": 1.0, "deadline_misses_by_cause": '
         '{"late_start": 1, "more_cpu": 0, "waited": 1}}',
         "counts 2 late frames, `deadline_misses` 3"),
    ],
)
def test_a_file_that_is_not_a_runs_json_is_refused(script, tmp_path, capsys, text, says) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text(text)
    assert script.main([str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"realtime_runs: error: {bad}: ") and says in err
