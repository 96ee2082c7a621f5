"""The exception hierarchy of splitrender.

::

    Exception
    └── SplitRenderError
        ├── InvalidInputError   (also a ValueError)
        ├── StreamError
        └── GpuUnavailableError (backend="wgpu" without a GPU adapter)

The classes are defined by the native module (so that the Rust code raises them directly) and
re-exported here; their ``__module__`` is ``splitrender.errors``. A Rust panic never reaches
Python as such: it is raised as ``SplitRenderError("internal error in ... (please report)")``.
"""

from splitrender._native import (
    GpuUnavailableError,
    InvalidInputError,
    SplitRenderError,
    StreamError,
)

__all__ = ["GpuUnavailableError", "InvalidInputError", "SplitRenderError", "StreamError"]
