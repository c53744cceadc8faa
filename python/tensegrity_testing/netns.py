"""Deprecated: `tensegrity_testing.netns` is `tensegrity.testing.netns` (this name is kept for one release)."""

import sys

from tensegrity.testing import netns as _module

sys.modules[__name__] = _module
