"""Deprecated: `tensegrity_testing.plugin` is `tensegrity.testing.plugin` (this name is kept for one release)."""

import sys

from tensegrity.testing import plugin as _module

sys.modules[__name__] = _module
