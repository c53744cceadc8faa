"""Deprecated: `tensegrity_testing.node` is `tensegrity.testing.node` (this name is kept for one release)."""

import sys

from tensegrity.testing import node as _module

sys.modules[__name__] = _module
