"""DDS domain ids leased for one test, shared with the Rust kit (`tensegrity::testing::DomainLease`).

A lease is a lock file `<tmp>/tensegrity-dds-domains/<id>` holding the owner's process id, created
exclusively and removed on release; a file whose process has ended is taken over. Ids come from
101 to 232, so parallel tests (in any language, any process) never share a domain.
"""

import itertools
import os
import tempfile

LEASED_DOMAINS = range(101, 233)
_sequence = itertools.count()


def directory():
    """Where the lock files live."""
    return os.path.join(tempfile.gettempdir(), "tensegrity-dds-domains")


class DomainLease:
    """A leased DDS domain id (`id`); `release()` (or garbage collection) gives it back."""

    def __init__(self):
        d = directory()
        os.makedirs(d, exist_ok=True)
        span = len(LEASED_DOMAINS)
        first = (os.getpid() * 7 + next(_sequence)) % span
        for k in range(span):
            domain = LEASED_DOMAINS[(first + k) % span]
            path = os.path.join(d, str(domain))
            if _try_take(path):
                self.id, self._path = domain, path
                return
        raise RuntimeError(f"every DDS domain id {LEASED_DOMAINS[0]}-{LEASED_DOMAINS[-1]} is leased ({d})")

    def release(self):
        """Removes the lock file if it is still ours."""
        path, self._path = getattr(self, "_path", None), None
        if path is None:
            return
        try:
            with open(path) as f:
                ours = f.read().strip() == str(os.getpid())
            if ours:
                os.remove(path)
        except OSError:
            pass

    def __del__(self):
        try:
            self.release()
        except Exception:  # at interpreter exit the builtins may already be gone
            pass


def _try_take(path):
    for _ in range(2):
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            try:
                with open(path) as f:
                    owner = int(f.read().strip())
            except (OSError, ValueError):
                return False
            if os.path.exists(f"/proc/{owner}"):
                return False
            try:  # stale: its owner has ended (two takers race on O_EXCL, one wins)
                os.remove(path)
            except OSError:
                pass
            continue
        with os.fdopen(fd, "w") as f:
            f.write(str(os.getpid()))
        return True
    return False
