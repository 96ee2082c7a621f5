"""What the live server and client add to aioquic so that a peer cannot make them buffer without
bound: receive windows raised by what the application was handed.

aioquic 1.x doubles a stream's receive window (MAX_STREAM_DATA) once the highest offset the peer
has sent on it passes half the window, and the connection's (MAX_DATA) once the sum of those
offsets passes half of its, however little of it arrived. A peer that sends one byte at the far
edge of a window makes the receiver zero-fill the gap in its reassembly buffer and doubles the
window: against ``splitrender serve``, eleven one-byte packets, sent before any hello, held a
gigabyte (the same rule is reported as aiortc/aioquic#589, closed without a fix). Here the same
rule reads the bytes delivered in order (``StreamDataReceived``) instead of the highest offset,
so a window grows as fast as the application reads it, as flow control intends (RFC 9000 §4.2),
and what a peer can make the receiver hold stays within the windows it started with: at most
``QuicConfiguration.max_data`` over all of a connection's streams, whose number aioquic keeps
at 128 of each kind at a time.

The hooks are aioquic's private methods ``_write_stream_limits`` and
``_write_connection_limits`` (pinned in pyproject.toml: ``aioquic>=1.7.2,<1.8``); a version that
lacks them raises at once instead of running unprotected, and
``tests/test_live.py::test_a_peer_cannot_inflate_the_servers_receive_windows`` sends the gap.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from aioquic.quic.connection import QuicConnection
from aioquic.quic.events import StreamDataReceived, StreamReset

__all__ = ["ReceiveWindows"]


class ReceiveWindows:
    """Installs the rule of the module's text on ``quic``; :meth:`delivered` must see every
    ``StreamDataReceived`` and ``StreamReset`` event of the connection."""

    def __init__(self, quic: QuicConnection) -> None:
        self._delivered: dict[int, int] = {}  # stream id -> bytes delivered in order
        self._total = 0  # over every stream, those finished included (as MAX_DATA counts)
        try:
            write_stream: Callable[..., None] = quic._write_stream_limits
            write_connection: Callable[..., None] = quic._write_connection_limits
            max_data = quic._local_max_data
        except AttributeError as e:  # another aioquic: refuse to run without the bound
            raise RuntimeError(
                f"this aioquic has no {e.name}: splitrender's receive-window bound needs "
                "aioquic 1.7 (pyproject.toml)"
            ) from None

        def stream_limits(builder: Any, space: Any, stream: Any) -> None:
            # aioquic raises the window when highest_offset * 2 > the window: let it see the
            # bytes delivered for the length of the call.
            receiver = stream.receiver
            highest = receiver.highest_offset
            receiver.highest_offset = self._delivered.get(stream.stream_id, 0)
            try:
                write_stream(builder, space, stream)
            finally:
                receiver.highest_offset = highest

        def connection_limits(builder: Any, space: Any) -> None:
            # The same for MAX_DATA: it is raised when used * 2 > its value.
            used = max_data.used
            max_data.used = min(used, self._total)
            try:
                write_connection(builder, space)
            finally:
                max_data.used = used

        quic._write_stream_limits = stream_limits  # type: ignore[method-assign]
        quic._write_connection_limits = connection_limits  # type: ignore[method-assign]

    def delivered(self, event: object) -> None:
        """Counts what ``event`` handed to the application (and forgets a finished stream)."""
        if isinstance(event, StreamDataReceived):
            n = len(event.data)
            self._total += n
            if event.end_stream:
                self._delivered.pop(event.stream_id, None)
            else:
                self._delivered[event.stream_id] = self._delivered.get(event.stream_id, 0) + n
        elif isinstance(event, StreamReset):
            self._delivered.pop(event.stream_id, None)
