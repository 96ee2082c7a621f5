"""The exception hierarchy of splitrender.

::

    Exception
    └── SplitRenderError
        ├── InvalidInputError   (also a ValueError)
        ├── StreamError
        ├── GpuUnavailableError (backend="wgpu" without a GPU adapter)
        └── ProtocolError       (a malformed or refused message of the live protocol)

The classes are defined by the native module (so that the Rust code raises them directly) and
re-exported here; their ``__module__`` is ``splitrender.errors``. :class:`ProtocolError` is raised
only by Python code (:mod:`splitrender.net.protocol`), so it is defined here. A Rust panic never reaches
Python as such: it is raised as ``SplitRenderError("internal error in ... (please report)")``.
"""

from splitrender._native import (
    GpuUnavailableError,
    InvalidInputError,
    SplitRenderError,
    StreamError,
)

__all__ = [
    "GpuUnavailableError",
    "InvalidInputError",
    "ProtocolError",
    "SplitRenderError",
    "StreamError",
]


class ProtocolError(SplitRenderError):
    """A message of the live protocol (docs/protocol.md) that is malformed, over a limit, of an
    unknown type or version, or refused (wrong token): the message names the field and what was
    expected. Whatever arrives from the network and fails to parse raises this, never another
    exception."""

    __module__ = "splitrender.errors"
