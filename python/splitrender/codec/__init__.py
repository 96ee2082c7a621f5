"""Server frame <-> packet: the HEVC/zstd coding of every buffer (:mod:`.coder`), the versioned
packet and stream-file format (:mod:`.stream`, docs/stream-format.md), and the encoding of a
whole recording into a stream file (:mod:`.encode`)."""

from splitrender.codec.coder import CodecConfig, DecodedStream, StreamDecoder, StreamEncoder
from splitrender.codec.stream import StreamStats, read_stream, stream_stats, write_stream

__all__ = [
    "CodecConfig",
    "DecodedStream",
    "StreamDecoder",
    "StreamEncoder",
    "StreamStats",
    "read_stream",
    "stream_stats",
    "write_stream",
]
