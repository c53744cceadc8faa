"""Deprecated: `tensegrity_testing.leases` is `tensegrity.testing.leases` (this name is kept for one release)."""

import sys

from tensegrity.testing import leases as _module

sys.modules[__name__] = _module
