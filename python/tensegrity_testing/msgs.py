"""Deprecated: `tensegrity_testing.msgs` is `tensegrity.testing.msgs` (this name is kept for one release)."""

import sys

from tensegrity.testing import msgs as _module

sys.modules[__name__] = _module
