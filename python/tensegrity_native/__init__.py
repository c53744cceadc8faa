"""Deprecated name of the library's extension: `tensegrity_native` is `tensegrity._native` (use
`import tensegrity`). Kept importable for one release."""

import sys
import warnings

warnings.warn(
    "tensegrity_native is deprecated: the extension is tensegrity._native, and the library is "
    "`import tensegrity` (tensegrity.Simulator, tensegrity.statics, ...)",
    DeprecationWarning,
    stacklevel=2,
)

from tensegrity import _native  # noqa: E402

sys.modules[__name__] = _native
