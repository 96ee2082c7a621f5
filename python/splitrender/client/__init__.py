"""The client: :class:`Client` (two server frames in, one display frame out, at the pose it is
given) and the playback of a whole session through the network model (:func:`play`)."""

from splitrender.client.client import Client
from splitrender.client.playback import PlaybackResult, play

__all__ = ["Client", "PlaybackResult", "play"]
