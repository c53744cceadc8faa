"""Deprecated: `tensegrity_testing.inprocess` is `tensegrity.testing.inprocess` (this name is kept for one release)."""

import sys

from tensegrity.testing import inprocess as _module

sys.modules[__name__] = _module
