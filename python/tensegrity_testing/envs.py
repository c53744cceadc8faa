"""Deprecated: `tensegrity_testing.envs` is `tensegrity.envs` (this name is kept for one release)."""

import sys

import tensegrity.envs as _module

sys.modules[__name__] = _module
