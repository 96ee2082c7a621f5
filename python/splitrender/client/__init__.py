"""The client: :class:`Client` (two server frames in, one display frame out, at the pose it is
given), the real-time loop a headset runs on top of it (:class:`RealtimeClient`: decoding and
pair preparation on a worker thread, one frame per display refresh by its deadline), and the
playback of a whole session through the network model (:func:`play`)."""

from splitrender.client.client import Client
from splitrender.client.playback import PlaybackResult, play
from splitrender.client.realtime import RealtimeClient, RealtimeReport

__all__ = ["Client", "PlaybackResult", "RealtimeClient", "RealtimeReport", "play"]
