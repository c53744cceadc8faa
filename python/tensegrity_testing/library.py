"""Deprecated: `tensegrity_testing.library` is `tensegrity.library` (this name is kept for one release)."""

import sys

import tensegrity.library as _module

sys.modules[__name__] = _module
