"""Deprecated: `tensegrity_testing.shm` is `tensegrity.testing.shm` (this name is kept for one release)."""

import sys

from tensegrity.testing import shm as _module

sys.modules[__name__] = _module
