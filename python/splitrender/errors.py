"""The exception hierarchy of splitrender.

::

    Exception
    └── SplitRenderError
        ├── InvalidInputError   (also a ValueError)
        ├── OutOfMemoryError    (also a MemoryError: legal sizes this machine cannot hold)
        ├── StreamError
        ├── GpuUnavailableError (backend="wgpu" without a GPU adapter)
        ├── GpuDeviceLostError  (the GPU device was lost: a driver reset, a removed GPU)
        └── ProtocolError       (a malformed or refused message of the live protocol)

The classes are defined by the native module (so that the Rust code raises them directly) and
re-exported here; their ``__module__`` is ``splitrender.errors``. :class:`ProtocolError` is raised
only by Python code (:mod:`splitrender.net.protocol`), so it is defined here. A Rust panic never reaches
Python as such: it is raised as ``SplitRenderError("internal error in ... (please report)")``.

Whose fault an error is follows from its class (:func:`is_user_error`): every *subclass* of
:class:`SplitRenderError` names something the caller gave (an argument, a file, a destination, a
backend, a peer's message, sizes too large for this machine), including those defined beside
their readers (``splitrender.scene``'s ``RecordingError``, ``DatasetError``, ``TraceError``) and
the argument errors of the evaluation commands. :class:`SplitRenderError` itself is raised only for failures
that are not the caller's: an internal error (a Rust panic), an external tool (ffmpeg) or the GPU
device failing; so is :class:`GpuDeviceLostError`, the one subclass that is not the caller's
either. The command line exits with status 2 for the first kind and 1 for the second.
"""

import errno
import socket

from splitrender._native import (
    GpuDeviceLostError,
    GpuUnavailableError,
    InvalidInputError,
    OutOfMemoryError,
    SplitRenderError,
    StreamError,
)

__all__ = [
    "GpuDeviceLostError",
    "GpuUnavailableError",
    "InvalidInputError",
    "OutOfMemoryError",
    "ProtocolError",
    "SplitRenderError",
    "StreamError",
    "is_user_error",
]

#: ``errno`` values of an :class:`OSError` about a path the caller named (missing, not allowed,
#: of the wrong kind, already there, read-only): the caller's to fix. Others (a full disk, an I/O
#: error, too many open files) are failures of the machine.
_USER_ERRNOS = frozenset({
    errno.ENOENT, errno.EACCES, errno.EPERM, errno.EISDIR, errno.ENOTDIR, errno.EEXIST,
    errno.ENOTEMPTY, errno.ENAMETOOLONG, errno.ELOOP, errno.EROFS, errno.EXDEV, errno.EINVAL,
    errno.EADDRINUSE, errno.EADDRNOTAVAIL,
})


class ProtocolError(SplitRenderError):
    """A message of the live protocol (docs/protocol.md) that is malformed, over a limit, of an
    unknown type or version, or refused (wrong token): the message names the field and what was
    expected. Whatever arrives from the network and fails to parse raises this, never another
    exception."""

    __module__ = "splitrender.errors"


def is_user_error(error: BaseException) -> bool:
    """Whether ``error`` is the caller's to fix, by its class alone (see the module's text): a
    subclass of :class:`SplitRenderError`, or an :class:`OSError` about a path or address the
    caller named (missing, not allowed, of the wrong kind, already there). ``SplitRenderError``
    itself, :class:`GpuDeviceLostError` and every other exception are failures inside the
    package or the machine."""
    if isinstance(error, SplitRenderError):
        return type(error) not in (SplitRenderError, GpuDeviceLostError)
    # A host name that does not resolve is the caller's too (its errno is the resolver's).
    return isinstance(error, socket.gaierror) or (
        isinstance(error, OSError) and error.errno in _USER_ERRNOS
    )
