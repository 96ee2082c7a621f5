"""The live protocol's messages (splitrender.net.protocol), the receive order of the client
(FrameOrder), the pose predictor, the adaptive bit-rate controller and the relay's draws: pure
logic, no network."""

from __future__ import annotations

import dataclasses
import asyncio
import math
import re
import struct
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

import splitrender.net.protocol as proto
from splitrender.client.live import FrameOrder
from splitrender.errors import InvalidInputError, ProtocolError, SplitRenderError, StreamError
from splitrender.net.abr import LeadController, LinkPacer, RateController
from splitrender.net.predict import ConstantVelocity, LastPose, make_predictor
from splitrender.net.relay import Impairment, Relay, _Direction, check_loopback


def _pose(t: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = Rotation.from_euler("y", 0.5 * t).as_matrix()
    m[:3, 3] = (t, 0.2 * t, -1.0)
    return m


def _header(seq: int, key: bool = False, size: int = 3) -> proto.FrameHeader:
    # Frame index 2·seq: the server skipped every other frame (the order follows seq).
    return proto.FrameHeader(2 * seq, seq, key, 0.1, 0.2, 5.0, 1e6, 10.0, 5.0, size)


# -- messages ------------------------------------------------------------------------------------


def test_round_trips() -> None:
    hello = proto.Hello("tok€n", 160, 90, 90.0)
    assert proto.decode_control(hello.encode()) == hello
    welcome = proto.Welcome(10.0, 0.0625, 160, 90, tuple(float(i) for i in range(16)), 100,
                            0.2, 0.05, "courtyard", bytes(range(32)))
    assert proto.decode_control(welcome.encode()) == welcome
    kr = proto.KeyRequest(41, proto.KEY_UNDECODABLE)
    assert proto.decode_control(kr.encode()) == kr
    ps = proto.PoseSample(7, 1.25, _pose(1.25))
    back = proto.decode_datagram(ps.encode())
    assert isinstance(back, proto.PoseSample) and back.seq == 7 and back.time == 1.25
    np.testing.assert_array_equal(back.pose, ps.pose)
    rr = proto.RateReport(3, 2.0, 1.5e6, 0.5, 12.5, 40, 2, 3, -42.5)
    assert proto.decode_datagram(rr.encode()) == rr
    fh = _header(12, True, 999)
    assert proto.FrameHeader.decode(fh.encode() + b"payload") == fh
    assert len(fh.encode()) == proto.FrameHeader.SIZE


def test_documented_sizes() -> None:
    """docs/protocol.md states these sizes."""
    assert len(proto.Hello("x" * proto.MAX_TOKEN).encode()) == 84
    assert len(proto.PoseSample(0, 0.0, np.eye(4)).encode()) == 109
    assert len(proto.RateReport(0, 0, 0, 0, 0, 0, 0).encode()) == 43
    assert proto.FrameHeader.SIZE == 63
    w = proto.Welcome(10.0, 0.1, 1, 1, (0.0,) * 16, 1, 1.0, 1.0, "s" * 255, bytes(32))
    assert len(w.encode()) == 457 <= proto.MAX_CONTROL


def test_every_close_code_is_documented_and_has_words() -> None:
    """docs/protocol.md's table of close codes; a close without a reason phrase reads as its
    code's words (a server's bare close read "code 0", a normal end, when it shut down)."""
    from pathlib import Path

    codes = {n: getattr(proto, n) for n in proto.__all__ if n.startswith("CLOSE_")
             and n != "CLOSE_TEXT"}
    assert sorted(codes.values()) == list(range(len(codes)))
    assert set(proto.CLOSE_TEXT) == set(codes.values())
    assert proto.CLOSE_TEXT[proto.CLOSE_SHUTDOWN] == "server shutting down"
    doc = (Path(__file__).parents[1] / "docs" / "protocol.md").read_text()
    for name, code in codes.items():
        assert f"| {code} | {name.removeprefix('CLOSE_')} |" in doc, name


def test_hello_refusals_name_the_field() -> None:
    raw = proto.Hello("t").encode()
    other = raw[:5] + struct.pack("<H", 9) + raw[7:]
    with pytest.raises(ProtocolError, match="protocol version 9 is not supported"):
        proto.Hello.decode(other)
    with pytest.raises(ProtocolError, match="magic"):
        proto.Hello.decode(raw[:1] + b"XXXX" + raw[5:])
    with pytest.raises(ProtocolError, match="token: at most 64"):
        proto.Hello("x" * 65).encode()
    long_token = raw[:7] + bytes([200]) + raw[8:]
    with pytest.raises(ProtocolError, match="token: at most 64"):
        proto.Hello.decode(long_token)
    with pytest.raises(ProtocolError, match="expected 21 bytes"):
        proto.Hello.decode(raw[:-1])
    with pytest.raises(ProtocolError, match="display size 5x0"):
        proto.Hello.decode(proto.Hello("t", 5, 1).encode()[:-12] + struct.pack("<HHd", 5, 0, 60))


def _welcome(**changes: Any) -> proto.Welcome:
    w = proto.Welcome(10.0, 0.1, 16, 9, (0.0,) * 16, 1, 1.0, 1.0, "courtyard", b"\xab" * 32)
    return dataclasses.replace(w, **changes)


def test_version_3_peers_are_refused_as_such() -> None:
    """Version 4 added the welcome's scene digest: a version 3 hello is refused with the
    version this side speaks, and a version 3 welcome (170 + N bytes, no digest) is refused
    for its version, not for its size, nor read as a welcome without a digest."""
    raw = proto.Hello("t").encode()
    v3 = raw[:5] + struct.pack("<H", 3) + raw[7:]  # a version 3 hello has this layout too
    with pytest.raises(ProtocolError, match=re.escape(
            "protocol version 3 is not supported (this server speaks version 4)")):
        proto.Hello.decode(v3)
    assert proto.hello_version(v3) == 3
    old = struct.Struct("<BHddHHHdd16dB")  # version 3's welcome
    name = b"courtyard"
    v3_welcome = old.pack(2, 3, 10.0, 0.1, 16, 9, 1, 1.0, 1.0, *(0.0,) * 16, len(name)) + name
    with pytest.raises(ProtocolError, match="welcome: protocol version 3, expected 4"):
        proto.decode_control(v3_welcome)
    with pytest.raises(ProtocolError, match="welcome: protocol version 3, expected 4"):
        proto.decode_control(_welcome(version=3).encode())


def test_the_welcomes_scene_digest_is_32_bytes_and_its_size_checked() -> None:
    w = _welcome(scene_digest=bytes(range(32)))
    raw = w.encode()
    # After the projection, before the name's length: 1 + 2 + 8 + 8 + 3·2 + 8 + 8 + 128 bytes.
    assert raw[169:201] == bytes(range(32)) and raw[201] == len("courtyard")
    assert proto.Welcome.decode(raw).scene_digest == bytes(range(32))
    for bad in (bytes(31), bytes(33), b"", "ab" * 32):
        with pytest.raises(ProtocolError, match="welcome.scene_digest: expected 32 bytes"):
            _welcome(scene_digest=bad).encode()
    # Sizes before use: a welcome cut inside the digest, a name other than its length says.
    with pytest.raises(ProtocolError, match="welcome: expected at least 202 bytes, got 190"):
        proto.decode_control(raw[:190])
    with pytest.raises(ProtocolError, match="welcome: expected 211 bytes, got 212"):
        proto.decode_control(raw + b"x")
    with pytest.raises(ProtocolError, match="welcome: expected 222 bytes, got 211"):
        proto.decode_control(raw[:201] + bytes([20]) + raw[202:])
    with pytest.raises(ProtocolError, match="welcome: expected at least 3 bytes, got 2"):
        proto.decode_control(raw[:2])


def test_datagram_limits_and_checks() -> None:
    with pytest.raises(ProtocolError, match="at most 256"):
        proto.decode_datagram(b"\x10" * 300)
    with pytest.raises(ProtocolError, match="unknown type 0x7f"):
        proto.decode_datagram(b"\x7f")
    with pytest.raises(ProtocolError, match="empty"):
        proto.decode_datagram(b"")
    bad = np.eye(4)
    bad[0, 0] = 2.0
    with pytest.raises(ProtocolError, match="not a rotation"):
        proto.decode_datagram(proto.PoseSample(1, 0.0, bad).encode())
    nan = proto.PoseSample(1, 0.0, np.eye(4)).encode()
    nan = nan[:5] + struct.pack("<d", math.nan) + nan[13:]
    with pytest.raises(ProtocolError, match="pose.time"):
        proto.decode_datagram(nan)


def test_frame_header_limits() -> None:
    raw = bytearray(_header(1).encode())
    struct.pack_into("<I", raw, proto.FrameHeader.SIZE - 5, proto.MAX_FRAME_PAYLOAD + 1)
    with pytest.raises(ProtocolError, match="frame header.size"):
        proto.FrameHeader.decode(bytes(raw))
    with pytest.raises(ProtocolError, match="at least 63 bytes"):
        proto.FrameHeader.decode(b"\x20" * 10)
    # The span: the last byte, 1..MAX_SPAN (0 would pair a frame with itself).
    spanned = dataclasses.replace(_header(1), span=proto.MAX_SPAN)
    assert proto.FrameHeader.decode(spanned.encode()).span == proto.MAX_SPAN
    for bad in (0, proto.MAX_SPAN + 1):
        raw = bytearray(spanned.encode())
        raw[-1] = bad
        with pytest.raises(ProtocolError, match=rf"frame header.span: expected 1..16, got {bad}"):
            proto.FrameHeader.decode(bytes(raw))


def test_control_reader_splits_and_limits() -> None:
    msgs = [proto.Hello("a").encode(), proto.KeyRequest(3).encode()]
    stream = b"".join(proto.frame_control(m) for m in msgs)
    r = proto.ControlReader()
    got = []
    for i in range(len(stream)):  # one byte at a time
        got += r.feed(stream[i : i + 1])
    assert got == msgs
    with pytest.raises(ProtocolError, match="message length 0"):
        proto.ControlReader().feed(b"\x00\x00")
    with pytest.raises(ProtocolError, match="message length 2000"):
        proto.ControlReader().feed(struct.pack("<H", 2000))


def test_each_field_from_the_wire_is_checked_and_named() -> None:
    """Every field check of the decoders, each met by a message that only it refuses (the
    fuzz tests above only ask that nothing but ProtocolError comes out, which a decoder that
    accepted these would satisfy too)."""
    def refused(decode: Any, raw: bytes | bytearray, message: str) -> None:
        with pytest.raises(ProtocolError, match=message):
            decode(bytes(raw))

    # A message of another type given to a decoder of one type.
    refused(proto.FrameHeader.decode, proto.KeyRequest(3).encode() + bytes(60),
            "^frame header: expected message type 0x20, got 0x03$")
    # The welcome (type B, version H, f_s d, scale d, then width, height and gop as u16).
    w = _welcome().encode()
    for at, value, message in [(19, 0, "welcome: size 0x9"), (21, 0, "welcome: size 16x0"),
                               (19, 65535, "welcome: size 65535x9"),
                               (23, 0, "welcome.gop: expected >= 1, got 0")]:
        raw = bytearray(w)
        struct.pack_into("<H", raw, at, value)
        refused(proto.decode_control, raw, f"^{re.escape(message)}")
    # The key request (type B, last q, reason B).
    k = proto.KeyRequest(3, proto.KEY_LOST).encode()
    refused(proto.decode_control, k[:1] + struct.pack("<q", -2) + k[9:],
            "^key request.last: expected >= -1, got -2$")
    for reason in (0, 4):
        refused(proto.decode_control, k[:9] + bytes([reason]),
                f"^key request.reason: expected 1, 2 or 3, got {reason}$")
    # The frame header (type B, index q, seq q, key B, ...).
    h = _header(1).encode()
    for at, fmt, value, message in [(1, "<q", -1, "frame header: index -1, seq 1: expected >= 0"),
                                    (9, "<q", -1, "frame header: index 2, seq -1: expected >= 0"),
                                    (17, "<B", 2, "frame header.key: expected 0 or 1, got 2")]:
        raw = bytearray(h)
        struct.pack_into(fmt, raw, at, value)
        refused(proto.FrameHeader.decode, raw, f"^{re.escape(message)}$")
    # What this side sends is held to the same limits.
    with pytest.raises(ProtocolError, match=rf"^hello.width: expected 0..{proto.MAX_SIDE}, got"):
        proto.Hello("t", proto.MAX_SIDE + 1, 9).encode()
    with pytest.raises(ProtocolError, match="^welcome.scene: at most 255 bytes, got 256$"):
        _welcome(scene="x" * 256).encode()
    with pytest.raises(ProtocolError, match="^welcome.proj: expected 16 values, got 15$"):
        _welcome(proj=(0.0,) * 15).encode()
    for message in (b"", bytes(proto.MAX_CONTROL + 1)):
        with pytest.raises(ProtocolError, match="^control message: expected 1..1024 bytes"):
            proto.frame_control(message)
    with pytest.raises(ProtocolError, match=r"^pose: expected a 4x4 matrix, got shape \(3, 4\)"):
        proto.PoseSample(1, 0.0, np.eye(4)[:3]).encode()
    # A reader with a small buffer refuses a message it would have to wait for beyond it.
    with pytest.raises(ProtocolError, match="^control stream: more than 10 bytes pending$"):
        proto.ControlReader(max_buffer=10).feed(struct.pack("<H", 100) + bytes(20))


@given(st.binary(max_size=600))
def test_fuzz_only_protocol_errors(data: bytes) -> None:
    """Whatever the bytes, the decoders return a message or raise ProtocolError."""
    for decode in (proto.decode_datagram, proto.decode_control, proto.FrameHeader.decode):
        try:
            decode(data)
        except ProtocolError:
            pass
    try:
        proto.ControlReader().feed(data)
    except ProtocolError:
        pass


@given(st.integers(0, 200), st.integers(0, 255))
def test_fuzz_mutated_messages(pos: int, byte: int) -> None:
    for raw in (proto.Hello("tok").encode(), _welcome().encode(),
                proto.PoseSample(1, 2.0, _pose(2.0)).encode(),
                proto.RateReport(1, 1, 1, 1, 1, 1, 1).encode(), _header(5).encode()):
        m = bytearray(raw)
        m[pos % len(m)] = byte
        for decode in (proto.decode_datagram, proto.decode_control, proto.FrameHeader.decode):
            try:
                decode(bytes(m))
            except ProtocolError:
                pass


def test_fingerprints() -> None:
    fp = proto.fingerprint_hex(b"cert")
    assert len(fp) == 95 and fp == fp.upper()
    assert proto.normalise_fingerprint(fp) == proto.normalise_fingerprint(fp.lower().replace(":", ""))
    with pytest.raises(ProtocolError, match="64 hex digits"):
        proto.normalise_fingerprint("abcd")
    assert issubclass(ProtocolError, SplitRenderError)


# -- the client's receive order ------------------------------------------------------------------


class _Log:
    def __init__(self) -> None:
        self.submitted: list[int] = []
        self.requests: list[tuple[int, int]] = []
        self.stopped: list[int] = []

    def order(self, give_up: float = 0.1) -> FrameOrder:
        return FrameOrder(
            lambda h, p: self.submitted.append(h.seq),
            lambda last, reason: self.requests.append((last, reason)),
            self.stopped.append,
            give_up,
        )


def test_order_in_sequence_and_reordered() -> None:
    log = _Log()
    o = log.order()
    o.complete(_header(0, True), b"", 0.0)
    o.complete(_header(2), b"", 0.01)  # 1 still in flight
    assert log.submitted == [0]
    o.complete(_header(1), b"", 0.02)
    assert log.submitted == [0, 1, 2] and not log.requests


def test_order_gap_before_key_frame_is_not_a_loss() -> None:
    log = _Log()
    o = log.order()
    o.complete(_header(0, True), b"", 0.0)
    o.complete(_header(4, True), b"", 0.1)  # 1..3 reset by the server (stale), then a key
    assert log.submitted == [0, 4] and o.lost == 0 and not log.requests


def test_order_gives_up_and_recovers_with_a_key_frame() -> None:
    log = _Log()
    o = log.order(give_up=0.1)
    o.complete(_header(0, True), b"", 0.0)
    o.started(1, 7)  # frame 1's stream: header seen, never completes
    o.complete(_header(2), b"", 0.05)
    o.tick(0.1)
    assert log.submitted == [0] and not log.requests  # still waiting for 1
    o.tick(0.2)
    assert o.lost == 1 and log.stopped == [7]
    assert log.requests == [(0, proto.KEY_LOST)]
    o.complete(_header(3), b"", 0.25)  # not decodable without 1: dropped
    assert log.submitted == [0]
    o.tick(1.3)  # no key frame for a second: asked again
    assert len(log.requests) == 2
    o.complete(_header(4, True), b"", 1.4)
    o.complete(_header(5), b"", 1.5)
    assert log.submitted == [0, 4, 5] and o.recoveries == 1
    o.complete(_header(1), b"", 1.6)  # a late retransmission of a given-up frame
    assert log.submitted == [0, 4, 5]


def test_order_undecodable_asks_once() -> None:
    log = _Log()
    o = log.order()
    o.complete(_header(0, True), b"", 0.0)
    o.complete(_header(1), b"", 0.1)
    o.undecodable(1, 0.2)
    o.undecodable(1, 0.21)
    assert log.requests == [(1, proto.KEY_UNDECODABLE)]
    o.complete(_header(2), b"", 0.3)
    assert log.submitted == [0, 1]
    o.complete(_header(3, True), b"", 0.4)
    assert log.submitted == [0, 1, 3] and o.recoveries == 1


def test_order_start_without_key_frame() -> None:
    log = _Log()
    o = log.order()
    o.complete(_header(5), b"", 0.0)
    assert log.requests == [(-1, proto.KEY_START)] and not log.submitted


def test_a_frame_headers_sent_time_is_a_time() -> None:
    # Any finite value was taken: -1e36 s made the client's queueing delay overflow the f32 of
    # its next report, which raised on the network thread (a traceback, and no more reports).
    good = proto.FrameHeader(3, 3, False, 0.2, 0.3, 0.25, 1e6, 1.0, 1.0, 100, 1)
    assert proto.FrameHeader.decode(good.encode()) == good
    bad = dataclasses.replace(good, sent=-1e36).encode()
    with pytest.raises(ProtocolError, match=r"frame header.sent: expected a finite number in "
                       r"\[-1e\+09, 1e\+09\]"):
        proto.FrameHeader.decode(bad)


def test_a_peers_text_is_printed_on_one_line() -> None:
    # A server's reason phrase was printed raw: a second "splitrender: error:" line of its
    # choosing, and escape sequences sent to the terminal.
    said = proto.printable("bad hello\nsplitrender: error: leaked\x1b[31mRED")
    assert said == "bad hello\\nsplitrender: error: leaked\\x1b[31mRED"
    assert said.isprintable()
    assert proto.printable("x" * 300) == "x" * 200 + "..."


# -- prediction, rate control, relay -------------------------------------------------------------


def test_constant_velocity_predicts_linear_motion() -> None:
    p = ConstantVelocity(window=0.05)
    assert p.predict(1.0) is None
    for i in range(10):
        p.add(i / 120, _pose(i / 120))
    p.add(0.0, _pose(5.0))  # reordered, older: ignored
    got = p.predict(0.3)
    assert got is not None
    np.testing.assert_allclose(got, _pose(0.3), atol=1e-9)
    assert p.newest_time == pytest.approx(9 / 120)
    # Beyond max_ahead it stops extrapolating.
    far = ConstantVelocity(max_ahead=0.1)
    far.add(0.0, _pose(0.0))
    far.add(0.01, _pose(0.01))
    np.testing.assert_allclose(far.predict(5.0), _pose(0.11), atol=1e-9)


def test_constant_velocity_is_bounded_by_what_the_peer_sends() -> None:
    """Its samples come from the network: a flood of them a nanosecond apart kept every one
    (the window holds 5e7), and two 5e-324 s apart made the extrapolation infinite (the
    session ended as a server error on a NaN rotation)."""
    p = ConstantVelocity(window=0.05)
    for i in range(10 * ConstantVelocity.MAX_SAMPLES):
        p.add(i * 1e-9, _pose(0.0))
    assert len(p._samples) == ConstantVelocity.MAX_SAMPLES
    q = ConstantVelocity()
    q.add(0.0, _pose(0.0))
    q.add(5e-324, _pose(0.001))
    np.testing.assert_array_equal(q.predict(0.4), _pose(0.001))  # no velocity: held
    # Far apart in position, the shortest baseline allowed and the longest look ahead: the
    # prediction stays where a pose may be.
    r = ConstantVelocity()
    r.add(0.0, _pose(-proto.MAX_POSITION / 2))
    r.add(ConstantVelocity.MIN_BASELINE_S, _pose(proto.MAX_POSITION))
    got = r.predict(1.0)
    assert got is not None and np.isfinite(got).all()
    assert np.abs(got[:3, 3]).max() == proto.MAX_POSITION


def test_last_pose_and_names() -> None:
    p = LastPose()
    p.add(1.0, _pose(1.0))
    p.add(0.5, _pose(0.5))
    np.testing.assert_array_equal(p.predict(9.0), _pose(1.0))
    assert isinstance(make_predictor("constant-velocity"), ConstantVelocity)
    with pytest.raises(InvalidInputError, match="predictor: expected one of"):
        make_predictor("oracle")


def test_the_link_rate_is_never_below_the_least_target() -> None:
    # A report of 1e-300 b/s became the link's rate, and the pacer held the next frame for
    # about 1e304 s: the session sent nothing more while poses kept coming.
    rc = RateController(1e6, 1e5, high_ms=50, low_ms=10)
    rc.update(1e-300, 500.0)
    assert rc.target_bps == 1e5 and rc.link_bps == 1e5
    pacer = LinkPacer()
    pacer.sent(0.0, 100_000, rc.link_bps)
    assert pacer.free_at(0.0, rc.link_bps) == pytest.approx(8.0)


def test_rate_controller_backs_off_and_climbs() -> None:
    rc = RateController(1e6, 1e5, high_ms=50, low_ms=10)
    assert rc.update(0.9e6, 0.0) == 1e6  # room, already at the top
    assert rc.update(0.4e6, 120.0) == pytest.approx(0.3e6)  # queue: to 75 % of what got through
    assert rc.update(0.4e6, 30.0) == pytest.approx(0.3e6)  # in between: hold
    # Room again: the climb is per second, whatever the report rate ...
    a, b = RateController(1e6, 1e5), RateController(1e6, 1e5)
    for r in (a, b):
        r.update(0.2e6, 500.0)  # to 0.15 Mb/s, the ceiling 0.2 ...
        # ... which a queue measured at a higher rate (a frame's bytes read late and at once)
        # does not raise: a full link is no wider link (a CI run climbed into the cap so)
        r.update(1e6, 500.0)
        assert r.ceiling_bps == 0.2e6
    for _ in range(2):
        a.update(0.0, 0.0, 0.25)
    b.update(0.0, 0.0, 0.5)
    # (the climb is capped by 75 % of the ceiling, which rises 3 % per second)
    assert a.target_bps == pytest.approx(b.target_bps) == pytest.approx(0.15e6 * 1.03**0.5)
    held = a.target_bps
    assert a.update(0.0, -1.0, 1.0) == held  # no frame since the last report: hold
    # ... and stops at 75 % of the rate that got through at the backoff, which rises 3 % per
    # second.
    assert rc.update(0.0, 0.0, 1.0) == pytest.approx(0.3e6 * 1.03)
    for _ in range(10):
        rc.update(0.0, 0.0, 1.0)
    assert rc.target_bps == pytest.approx(0.3e6 * 1.03**11)
    for _ in range(50):
        rc.update(0.0, 0.0, 1.0)
    assert rc.target_bps == 1e6  # never above the top
    assert rc.update(1e3, 500.0) == 1e5  # never below the floor
    with pytest.raises(InvalidInputError, match="bit-rate range"):
        RateController(1e5, 1e6)


def test_lead_follows_late_frames() -> None:
    lead = LeadController(margin_ms=20, decay=0.1, max_s=0.5)
    assert lead.update(0, 300.0) == 0.0  # no frame made usable: no news
    assert lead.update(2, 80.0) == pytest.approx(0.1)  # late by 80 ms: 100 ms earlier
    assert lead.update(1, -20.0) == pytest.approx(0.1)  # early by the margin: hold
    assert lead.update(1, -120.0) == pytest.approx(0.09)  # early: a tenth of the excess back
    assert lead.update(1, 2000.0) == 0.5  # at most max_s
    for _ in range(200):
        lead.update(1, -1000.0)
    assert lead.lead_s == 0.0


def test_link_pacer_drains_at_the_measured_rate() -> None:
    pacer = LinkPacer()
    pacer.sent(0.0, 10_000, 0.4e6)  # 80 kbit: 0.2 s at 0.4 Mb/s
    assert pacer.free_at(0.0, 0.4e6) == pytest.approx(0.2)
    assert pacer.free_at(0.1, 0.4e6) == pytest.approx(0.2)  # half of it crossed
    pacer.sent(0.1, 5_000, 0.4e6)  # queued behind the rest
    assert pacer.free_at(0.1, 0.4e6) == pytest.approx(0.3)
    # A narrower link found later drains what is left more slowly (80 kbit at 0.2 Mb/s).
    assert pacer.free_at(0.1, 0.2e6) == pytest.approx(0.5)
    assert pacer.free_at(1.0, 0.2e6) == 1.0  # all crossed: free now
    # Unmeasured (no backoff yet): nothing says the link is narrower than what is sent.
    pacer.sent(1.0, 100_000, None)
    assert pacer.free_at(1.0, None) == 1.0
    rc = RateController(1e6, 1e5)
    assert rc.link_bps is None
    rc.update(0.4e6, 500.0)
    assert rc.link_bps == 0.4e6


def test_plan_after_a_large_frame_waits_for_the_link() -> None:
    from splitrender.net.server import plan_frame

    fs, after = 5.0, 0.01
    base = dict(
        client_now=10.0, offset=0.0, fs=fs, span=1, last=50, ahead=0.1 + after, after=after
    )
    # An empty link: the next frame of the grid (51, needed at 50/f_s = 10.0 s) cannot be
    # there in time from 10.0 (0.11 s of work); 52 (needed at 10.2) can, started 10.09.
    plan = plan_frame(**base, queued=0.0)
    assert (plan.k, plan.skipped) == (52, 1) and plan.start == pytest.approx(10.09)
    # The reopening key frame still on the link for 0.25 s: 52's bytes would queue behind it
    # (free at 10.25 > 10.2 - owd). Planned for 53 instead, which arrives in time.
    plan = plan_frame(**base, queued=0.25)
    assert (plan.k, plan.skipped) == (53, 2)
    assert 10.0 + 0.25 + after <= (plan.k - 1) / fs
    assert plan.start == pytest.approx((plan.k - 1) / fs - 0.11)
    # Span 2 keeps to its grid (even k); the first frame of a session is for when it arrives.
    assert plan_frame(**{**base, "span": 2}, queued=0.25).k == 54
    assert plan_frame(**{**base, "last": -1}, queued=0.0) == plan_frame(
        **{**base, "last": -1}, queued=0.05
    )


def test_choose_span_fits_the_render_time_with_hysteresis() -> None:
    from splitrender.net.server import SPAN_CALM, choose_span

    # At f_s 10 a frame may take 0.8 of its span's period: 80 ms at span 1, 160 at span 2.
    assert choose_span(0.080, 10.0, 1, 0) == (1, 0)
    assert choose_span(0.081, 10.0, 1, 0) == (2, 0)
    assert choose_span(0.300, 10.0, 1, 0) == (4, 0)  # at once, however far
    assert choose_span(10.0, 10.0, 1, 0) == (16, 0)  # at most MAX_SPAN
    assert choose_span(0.300, 10.0, 1, 0, max_span=1) == (1, 0)  # --max-span 1: skip instead
    # Back to a shorter span only after SPAN_CALM frames in a row that fit it.
    span, calm = 4, 0
    for i in range(SPAN_CALM - 1):
        span, calm = choose_span(0.05, 10.0, span, calm)
        assert (span, calm) == (4, i + 1)
    assert choose_span(0.05, 10.0, span, calm) == (1, 0)
    # A frame that does not fit the shorter span restarts the count.
    assert choose_span(0.25, 10.0, 4, 3) == (4, 0)
    # Going back needs room (60 % of the shorter period): 70 ms fits span 1 by SPAN_LOAD, but
    # a span-2 server stays at 2 instead of switching back and forth around the boundary.
    assert choose_span(0.070, 10.0, 1, 0) == (1, 0)
    assert choose_span(0.070, 10.0, 2, SPAN_CALM - 1) == (2, 0)
    assert choose_span(0.059, 10.0, 2, SPAN_CALM - 1) == (1, 0)


def test_relay_schedule_starts_with_the_first_client_datagram() -> None:
    """The bandwidth steps count from a client's first datagram (the session's start), and
    each is reported with the loop's clock (time.monotonic) as it is applied."""
    steps: list[tuple[str, float, float]] = []

    async def run() -> tuple[float, float]:
        loop = asyncio.get_running_loop()
        relay = Relay(("127.0.0.1", 9), Impairment(), Impairment(schedule=((0.05, 1.0),)),
                      on_step=lambda d, mbps, when: steps.append((d, mbps, when)))
        await relay.start()
        try:
            await asyncio.sleep(0.2)
            assert steps == []  # no client yet: the schedule has not started
            sock, _ = await loop.create_datagram_endpoint(
                asyncio.DatagramProtocol, remote_addr=("127.0.0.1", relay.port))
            sent = loop.time()
            sock.sendto(b"x")
            for _ in range(100):
                await asyncio.sleep(0.02)
                if steps:
                    break
            sock.close()
            return sent, relay._dirs["down"].rate_bps
        finally:
            relay.close()

    sent, rate = asyncio.run(asyncio.wait_for(run(), 10))
    assert rate == 1e6 and [(d, m) for d, m, _ in steps] == [("down", 1.0)]
    assert sent + 0.05 <= steps[0][2] < sent + 1.5


def test_relay_draws_are_seeded() -> None:
    imp = Impairment(delay_ms=50, jitter_ms=20, loss=0.1, bandwidth_mbps=1.0, queue_ms=100)

    def fates(seed: int) -> list[float | None]:
        d = _Direction(imp, seed)
        return [d.fate(1200, i * 0.005) for i in range(300)]

    a, b = fates(1), fates(1)
    assert a == b and a != fates(2)
    lost = sum(f is None for f in a)
    assert 10 <= lost <= 60
    kept = [f for f in a if f is not None and f >= 0]
    assert all(0.03 - 1e-9 <= f <= 0.07 + 0.1 + 0.01 for f in kept)
    # 1200 B every 5 ms is 1.92 Mb/s into a 1 Mb/s link: the queue fills and drops.
    assert any(f == -1.0 for f in a)


@pytest.mark.parametrize(
    ("make", "problem"),
    [
        (lambda: Impairment(delay_ms=-1.0), "delay_ms: expected a finite number >= 0"),
        (lambda: Impairment(jitter_ms=math.nan), "jitter_ms: expected a finite number >= 0"),
        (lambda: Impairment(bandwidth_mbps=math.inf),
         "bandwidth_mbps: expected a finite number >= 0"),
        (lambda: Impairment(queue_ms=-5.0), "queue_ms: expected a finite number >= 0"),
        (lambda: Impairment(loss=1.0), r"loss: expected a fraction in \[0, 1\)"),
        (lambda: Impairment(schedule=((-1.0, 5.0),)),
         "bandwidth schedule: expected SECONDS:MBPS >= 0, got -1.0:5.0"),
        (lambda: Impairment(schedule=((1.0, math.nan),)),
         "bandwidth schedule: expected SECONDS:MBPS >= 0, got 1.0:nan"),
        (lambda: LeadController(max_s=-1.0), "lead: expected max_s >= 0"),
        (lambda: LeadController(max_s=math.nan), "lead: expected max_s >= 0"),
        (lambda: ConstantVelocity(window=0.0), "ConstantVelocity: expected window > 0"),
        (lambda: ConstantVelocity(window=math.nan), "ConstantVelocity: expected window > 0"),
        (lambda: ConstantVelocity(max_ahead=math.inf), "ConstantVelocity: expected window > 0"),
    ],
)
def test_link_and_controller_settings_out_of_range_are_refused(
    make: Any, problem: str
) -> None:
    with pytest.raises(InvalidInputError, match=f"^{problem}"):
        make()


def test_relay_stays_on_loopback() -> None:
    assert check_loopback("127.0.0.1", "x") == "127.0.0.1"
    with pytest.raises(InvalidInputError, match="loopback"):
        # A reserved name (RFC 2606) that is refused before any lookup: nothing is contacted.
        Relay(("relay.invalid", 4433), Impairment(), Impairment())
    with pytest.raises(InvalidInputError, match="loss"):
        Impairment(loss=1.0)


# -- the encoder's live controls and the client's time-indexed decoding -------------------------


@pytest.mark.parametrize("start, then", [(0.3, 0.6), (0.6, 0.3)])
def test_encoder_lands_on_a_new_target_after_set_bitrate(start: float, then: float) -> None:
    """The live server moves the target (set_bitrate + a key frame); the frames after it are
    sized for the new target, not corrected by how the previous GOP met the old one (which
    had overshot a climb by ~45 % and undershot a drop by ~45 % here; now ~15 % and ~10 %)."""
    import dataclasses

    import splitrender as sr

    scene = sr.SyntheticScene(dynamic=True)
    fps = 10.0
    with sr.StreamEncoder(sr.CodecConfig(bitrate_mbps=start, fps=fps, gop=100, threads=1)) as enc:
        sizes = []
        for i in range(48):
            if i in (8, 16, 32, 40):
                enc.request_key_frame()
            if i == 24:
                enc.set_bitrate(then)
                enc.request_key_frame()
            f = scene.server_frame(i, i / fps, 77, 43, fps=fps)
            sizes.append(len(enc.encode(dataclasses.replace(f, index=i))))
    per_frame = then * 1e6 / 8 / fps
    assert 0.7 < np.mean(sizes[26:]) / per_frame < 1.3, sizes


def test_encoder_live_controls_and_seq_indexed_packets() -> None:
    """StreamEncoder.request_key_frame/set_bitrate (the live server's hooks), and packets
    indexed by their place in the sequence (seq) while the frames skip indices: the client's
    decoder gets the frame index back from the time."""
    import dataclasses

    import splitrender as sr
    from splitrender.client.live import _TimeIndexed
    from splitrender.codec.stream import peek_header

    scene = sr.SyntheticScene(dynamic=True)
    fps = 10.0
    ks = [0, 1, 4, 5, 9]  # the server skipped 2, 3, 6, 7, 8
    frames = [scene.server_frame(k, k / fps, 32, 24, fps=fps) for k in ks]
    with sr.StreamEncoder(sr.CodecConfig(bitrate_mbps=0.5, fps=fps, gop=100, threads=1)) as enc:
        packets = []
        for seq, f in enumerate(frames):
            if seq == 2:
                enc.request_key_frame()
            if seq == 3:
                enc.set_bitrate(0.25)
                assert enc.config.bitrate_mbps == 0.25
            packets.append(enc.encode(dataclasses.replace(f, index=seq)))
    keys = [peek_header(p)[1] for p in packets]
    assert keys == [True, False, True, False, False]  # a rate change alone waits for a key
    with pytest.raises(InvalidInputError):
        sr.StreamEncoder().set_bitrate(0.0)
    proj = tuple(frames[0].main.camera.proj.ravel())
    dec = _TimeIndexed(proto.Welcome(fps, 1.0, 32, 24, proj, 100, 0.5, 0.1, "synthetic",
                                     bytes(32)))
    try:
        assert [dec.decode(p).index for p in packets] == ks
    finally:
        dec.close()
    # Its pixels are bounded by the welcome's size: packets of this server's larger cameras
    # (the decoder's own bound is 2^25 pixels, a gigabyte of buffers) are refused.
    small = _TimeIndexed(proto.Welcome(fps, 1.0, 16, 12, proj, 100, 0.5, 0.1, "synthetic",
                                       bytes(32)))
    try:
        with pytest.raises(StreamError, match="exceeds the decoder's limit of 384 pixels"):
            small.decode(packets[0])
    finally:
        small.close()


def test_messages_at_the_limits_of_the_protocol_round_trip() -> None:
    # Each limit itself is a message (one past it is refused: the tests above); the ends of
    # every range a decoder checks.
    for hello in (
        proto.Hello("t" * proto.MAX_TOKEN, proto.MAX_SIDE, proto.MAX_SIDE, proto.MAX_FPS),
        proto.Hello("", 1, 1, proto.MIN_DISPLAY_FPS),
        proto.Hello("a", 0, 0),
    ):
        assert proto.decode_control(hello.encode()) == hello
    for side in (1, proto.MAX_SIDE):
        w = proto.Welcome(10.0, 0.1, side, side, (0.0,) * 16, 1, 1.0, 1.0, "s", bytes(32))
        assert proto.decode_control(w.encode()) == w
    none_yet = proto.KeyRequest(-1, proto.KEY_START)
    assert proto.decode_control(none_yet.encode()) == none_yet
    for index, size, span in [(0, 1, 1), (2**40, proto.MAX_FRAME_PAYLOAD, proto.MAX_SPAN)]:
        h = proto.FrameHeader(index, index, True, 0.0, 0.1, 0.0, 1e6, 1.0, 1.0, size, span)
        assert proto.FrameHeader.decode(h.encode()) == h
    # The longest control message, framed and read back in pieces.
    longest = bytes(proto.MAX_CONTROL)
    framed = proto.frame_control(longest)
    reader = proto.ControlReader(max_buffer=len(framed))
    assert reader.feed(framed[:100]) == [] and reader.feed(framed[100:]) == [longest]
    with pytest.raises(ProtocolError, match=f"expected 1..{proto.MAX_CONTROL} bytes, got "
                                            f"{proto.MAX_CONTROL + 1}$"):
        proto.frame_control(longest + b"x")
    # A message still arriving may fill the reader's buffer, not pass it.
    reader = proto.ControlReader(max_buffer=10)
    assert reader.feed(struct.pack("<H", 100) + bytes(8)) == []
    with pytest.raises(ProtocolError, match="^control stream: more than 10 bytes pending$"):
        reader.feed(b"x")
    # A frame carries a packet: a header announcing none is refused.
    empty = proto.FrameHeader(0, 0, True, 0.0, 0.1, 0.0, 1e6, 1.0, 1.0, 0)
    with pytest.raises(ProtocolError, match=f"^frame header.size: expected "
                                            f"1..{proto.MAX_FRAME_PAYLOAD} bytes, got 0$"):
        proto.FrameHeader.decode(empty.encode())
