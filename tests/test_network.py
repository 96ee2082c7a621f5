"""splitrender.net.model: the link model and the client schedule (REFERENCE.md §2.1)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from splitrender.errors import InvalidInputError
from splitrender.net.model import (
    MAX_ALPHA,
    FrameBuffer,
    NetworkModel,
    Schedule,
    choose_frames,
)

F = 12  # client frames per server frame at f_c = 120, f_s = 10


def test_ideal_link_delivers_at_send_time() -> None:
    sends = [0.0, 0.1, 0.1, 0.3]
    assert NetworkModel().arrival_times(sends) == sends


def test_bandwidth_serialises_packets_in_a_fifo() -> None:
    net = NetworkModel(bandwidth_mbps=1.0)  # 1250 bytes take 10 ms
    arr = net.arrival_times([0.0, 0.0, 0.0, 0.5], [1250, 1250, 2500, 1250])
    assert arr == pytest.approx([0.010, 0.020, 0.040, 0.510])


def test_latency_and_extra_delay_add_up() -> None:
    net = NetworkModel(latency_ms=20.0, extra_delay_frames=3, client_fps=120.0)
    assert net.arrival_times([1.0]) == pytest.approx([1.0 + 0.020 + 3 / 120])


def test_jitter_is_bounded_seeded_and_never_reorders() -> None:
    sends = [i * 0.001 for i in range(500)]
    a = NetworkModel(jitter_ms=30.0, seed=7).arrival_times(sends)
    b = NetworkModel(jitter_ms=30.0, seed=7).arrival_times(sends)
    c = NetworkModel(jitter_ms=30.0, seed=8).arrival_times(sends)
    assert a == b and a != c
    d = np.array(a, dtype=float) - np.array(sends)
    assert d.min() >= 0.0 and d.max() <= 0.030 + 1e-12
    assert all(x <= y for x, y in itertools.pairwise(a))  # in-order delivery


def test_loss_is_seeded_and_near_its_rate() -> None:
    sends = [i * 0.01 for i in range(4000)]
    a = NetworkModel(loss=0.1, seed=1).arrival_times(sends)
    assert a == NetworkModel(loss=0.1, seed=1).arrival_times(sends)
    lost = sum(x is None for x in a)
    assert 300 < lost < 500
    assert all(x is None for x in NetworkModel(loss=1.0).arrival_times(sends[:10]))
    # a lost packet still occupies the link
    arr = NetworkModel(bandwidth_mbps=1.0, loss=1.0).link()
    assert arr.send(0.0, 1250) is None
    # 1250 bytes take 10 ms: packet i sent at 0 arrives at 10 (i + 1) ms whether or not the
    # ones before it were lost.
    a = NetworkModel(bandwidth_mbps=1.0, loss=0.5, seed=3).arrival_times([0.0] * 8, [1250] * 8)
    assert a[:4] == [None] * 4 and a[4] is not None  # seed 3 loses the first four
    for i, x in enumerate(a):
        assert x is None or x == pytest.approx(0.010 * (i + 1)), (i, x)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"latency_ms": -1.0}, "latency_ms"),
        ({"loss": 1.5}, "loss"),
        ({"bandwidth_mbps": 0.0}, "bandwidth_mbps"),
        ({"extra_delay_frames": -1}, "extra_delay_frames"),
        ({"extra_delay_frames": 1.5}, "extra_delay_frames"),
        ({"jitter_ms": float("nan")}, "jitter_ms"),
    ],
)
def test_invalid_network_parameters(kwargs: dict[str, float], match: str) -> None:
    with pytest.raises(InvalidInputError, match=match):
        NetworkModel(**kwargs)  # type: ignore[arg-type]


def test_invalid_sends() -> None:
    with pytest.raises(InvalidInputError, match="non-decreasing"):
        NetworkModel().arrival_times([0.2, 0.1])
    with pytest.raises(InvalidInputError, match="sizes"):
        NetworkModel(bandwidth_mbps=10.0).arrival_times([0.0])
    with pytest.raises(InvalidInputError, match="one size per send time"):
        NetworkModel().arrival_times([0.0, 0.1], [1])
    with pytest.raises(InvalidInputError, match="size"):
        NetworkModel().arrival_times([0.0], [-1])


def reference_entry(n: int, latency: int) -> tuple[str, int | None, int, float]:
    """REFERENCE.md §2.1 for client frame n = iF + b with latency l (older None when only the
    newer frame is used)."""
    i, b = divmod(n, F)
    if b < latency:
        return ("extrapolate", None, i, (F + b) / F)
    return ("interpolate", i, i + 1, b / F)


def test_a_network_made_for_another_client_rate_is_refused() -> None:
    # The extra delay is counted in client frames: a link made for 60 FPS would delay a 120 FPS
    # schedule by half its frames.
    net = NetworkModel(extra_delay_frames=2, client_fps=60.0)
    with pytest.raises(InvalidInputError, match=r"^network.client_fps: expected the schedule's "
                       r"client_fps = 120.0, got 60.0$"):
        Schedule.build([0.0, 0.1], network=net, client_fps=120.0)
    assert len(Schedule.build([0.0, 0.1], network=net, client_fps=60.0).entries) > 0


@pytest.mark.parametrize("latency", [0, 1, 2, 4, 8, 11, 12])
def test_schedule_follows_reference_latency(latency: int) -> None:
    s = Schedule.build(11, NetworkModel(extra_delay_frames=latency))
    assert len(s.entries) == 10 * F
    for n, e in enumerate(s.entries):
        mode, older, newer, alpha = reference_entry(n, latency)
        assert (e.mode, e.older, e.newer) == (mode, older, newer), n
        assert e.alpha == pytest.approx(alpha, abs=1e-12)
        assert e.time == n / 120
    summary = s.summary()
    assert summary["extrapolate"] == 10 * min(latency, F)
    assert summary["hold"] == 0


def test_l12_always_extrapolates_from_the_newest_frame() -> None:
    s = Schedule.build(6, NetworkModel(extra_delay_frames=12))
    assert set(s.modes()) == {"extrapolate"}
    # b = 0 is exactly alpha = 1 (snapped), never 0.999...: extrapolation, not interpolation.
    assert [e.alpha for e in s.entries[::F]] == [1.0] * 5


def test_latency_in_ms_equals_extra_frames() -> None:
    a = Schedule.build(8, NetworkModel(latency_ms=25.0))  # 3 client frames at 120 FPS
    b = Schedule.build(8, NetworkModel(extra_delay_frames=3))
    assert [(e.mode, e.older, e.newer) for e in a.entries] == [
        (e.mode, e.older, e.newer) for e in b.entries
    ]


def test_bandwidth_cap_delays_like_extra_frames() -> None:
    # 1 Mbit per frame at 20 Mb/s: 50 ms = 6 client frames of serialisation.
    sizes = [125_000] * 8
    a = Schedule.build(8, NetworkModel(bandwidth_mbps=20.0), frame_sizes=sizes)
    b = Schedule.build(8, NetworkModel(extra_delay_frames=6))
    assert a.modes() == b.modes()
    assert a.arrivals == pytest.approx([k / 10 - 0.1 + 0.05 for k in range(8)])


def test_a_lost_frame_extrapolates_across_the_gap_and_recovers() -> None:
    lost = Schedule.build(8, _DropNetwork(drop={3}))
    assert lost.arrivals[3] is None
    for n, e in enumerate(lost.entries):
        i, b = divmod(n, F)
        if i == 2:  # pair (2, 3) missing: extrapolate from 2
            assert (e.mode, e.newer, e.alpha) == ("extrapolate", 2, pytest.approx(1 + b / F))
        elif i == 3:  # frame 3 never came: still from 2, alpha in [2, 3)
            assert (e.mode, e.newer, e.alpha) == ("extrapolate", 2, pytest.approx(2 + b / F))
        else:
            assert e.mode == "interpolate" and e.older == i
    assert all(e.alpha is not None and e.alpha <= MAX_ALPHA for e in lost.entries)


class _DropNetwork(NetworkModel):
    """An ideal network that loses exactly the packets in ``drop`` (by send order)."""

    def __init__(self, drop: set[int]) -> None:
        super().__init__()
        object.__setattr__(self, "_drop", drop)

    def arrival_times(self, send_times, sizes=None):  # type: ignore[no-untyped-def]
        arr = super().arrival_times(send_times, sizes)
        return [None if i in self._drop else a for i, a in enumerate(arr)]  # type: ignore[attr-defined]


def test_beyond_max_alpha_holds() -> None:
    lost = Schedule.build(8, _DropNetwork(drop={2, 3, 4}))
    # frame 1 is the newest: alpha = 1 + (t - 0.1) * 10 exceeds 3 from t = 0.3 (period 3) on.
    assert [e.mode for e in lost.entries[2 * F : 3 * F]] == ["extrapolate"] * F
    assert lost.entries[3 * F].mode == "extrapolate" and lost.entries[3 * F].alpha == 3.0
    assert all(e.mode == "hold" for e in lost.entries[3 * F + 1 : 5 * F])
    assert {e.mode for e in lost.entries[5 * F :]} == {"interpolate"}  # recovered


def test_holds_before_the_first_frame_arrives() -> None:
    # No lead: frame 0 leaves at t = 0 and needs 20 ms.
    s = Schedule.build(4, NetworkModel(latency_ms=20.0), lead=0.0)
    assert s.modes()[:3] == ["hold"] * 3  # t = 0, 8.3, 16.7 ms
    e = s.entries[3]  # t = 25 ms
    assert (e.mode, e.older, e.newer) == ("extrapolate", None, 0)
    assert e.alpha == pytest.approx(1.25)


@pytest.mark.parametrize("method", ["ours_extrapolate", "forward_splat", "timewarp"])
def test_unidirectional_methods_always_extrapolate(method: str) -> None:
    s = Schedule.build(5, method=method)
    assert set(s.modes()) == {"extrapolate"}
    for n, e in enumerate(s.entries):
        assert e.newer == n // F and e.older is None
        assert e.alpha == pytest.approx(1 + (n % F) / F)


def test_forward_splat_bidirectional_interpolates() -> None:
    s = Schedule.build(5, method="forward_splat", splat_bidirectional=True)
    assert set(s.modes()) == {"interpolate"}


def test_backward_bidir_holds_while_late() -> None:
    s = Schedule.build(5, NetworkModel(extra_delay_frames=4), method="backward_bidir")
    for n, e in enumerate(s.entries):
        assert e.mode == ("hold" if n % F < 4 else "interpolate")


def test_choose_frames_rules() -> None:
    held = {4: 0.4, 5: 0.5}
    e = choose_frames(held, 0.45)
    assert (e.mode, e.older, e.newer, e.alpha) == ("interpolate", 4, 5, pytest.approx(0.5))
    assert e.frames == (4, 5)
    e = choose_frames(held, 0.5)  # at the newer frame's own time: alpha = 1 from it alone
    assert (e.mode, e.older, e.newer, e.alpha) == ("extrapolate", None, 5, 1.0)
    e = choose_frames(held, 0.3)
    assert (e.mode, e.frames, e.alpha) == ("hold", (), None)
    assert choose_frames({}, 1.0).mode == "hold"
    with pytest.raises(InvalidInputError, match="unknown method"):
        choose_frames(held, 0.45, method="magic")


def test_choose_frames_pairs_frames_of_one_span() -> None:
    # A server at f_s 10 that renders every 2nd frame: frames 4 and 6, motion spanning 0.2 s.
    held, spans = {4: 0.4, 6: 0.6}, {4: 2, 6: 2}
    e = choose_frames(held, 0.45, spans=spans)
    assert (e.mode, e.older, e.newer, e.alpha) == ("interpolate", 4, 6, pytest.approx(0.25))
    # Without the spans, 4 and 6 are not a pair (frame 5 is missing): extrapolation.
    assert choose_frames(held, 0.45).mode == "extrapolate"
    # Extrapolating from a frame of span 2 counts α in its own period: 0.1 s is half of it.
    e = choose_frames(held, 0.7, spans=spans)
    assert (e.mode, e.newer, e.alpha) == ("extrapolate", 6, pytest.approx(1.5))
    # ... and holds after 2 of its periods (α 3), not after 2 of f_s's.
    assert choose_frames(held, 0.95, spans=spans).mode == "extrapolate"
    assert choose_frames(held, 1.05, spans=spans).mode == "hold"
    # Frames of different spans do not pair: 5's motion reaches 6 and 6's reaches 4.
    e = choose_frames({5: 0.5, 6: 0.6}, 0.55, spans={5: 1, 6: 2})
    assert (e.mode, e.newer) == ("extrapolate", 5)
    e = choose_frames({4: 0.4, 6: 0.6}, 0.45, spans={4: 2, 6: 1})
    assert (e.mode, e.newer) == ("extrapolate", 4)


def test_frame_buffer_refuses_duplicates_stale_and_overflow() -> None:
    buf = FrameBuffer(capacity=3)
    assert buf.receive(0, 0.0) and buf.receive(1, 0.1)
    assert not buf.receive(1, 0.1)  # duplicate
    buf.prune(0.15)  # frame 0 can no longer be used
    assert sorted(buf.times) == [1]
    assert not buf.receive(0, 0.0)  # stale
    assert buf.receive(2, 0.2) and buf.receive(3, 0.3)
    assert not buf.receive(4, 0.4)  # full: the newest is refused, not the needed oldest
    b = FrameBuffer()
    b.receive(1, 0.1)
    with pytest.raises(InvalidInputError, match="increasing"):
        b.receive(2, 0.05)
