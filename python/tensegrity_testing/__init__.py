"""Deprecated name of the test kit: `tensegrity_testing` is `tensegrity.testing`, its
`envs` is `tensegrity.envs` and its `library` is `tensegrity` itself. Kept importable for one
release: each old module is the new one under its old name."""

import warnings

warnings.warn(
    "tensegrity_testing is deprecated: use tensegrity.testing (the test kit), tensegrity.envs (the "
    "Gymnasium environments) and tensegrity (the library)",
    DeprecationWarning,
    stacklevel=2,
)

from tensegrity.testing import *  # noqa: E402,F401,F403
from tensegrity.testing import __all__  # noqa: E402,F401
