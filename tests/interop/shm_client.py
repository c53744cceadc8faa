"""The shared-memory client's command line (`--check`, `--bench`, `--sizes`): the Python test
kit's `tensegrity.testing.shm` (in python/ of this repository, also installable with
`pip install ./python`), run from a checkout without installing it: the module is loaded from its
file (it imports nothing else of the package, and the package itself needs its built extension)."""

import importlib.util
import pathlib
import sys

_path = pathlib.Path(__file__).resolve().parents[2] / "python" / "tensegrity" / "testing" / "shm.py"
_spec = importlib.util.spec_from_file_location("tensegrity_shm_client", _path)
_shm = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = _shm  # ctypes structures and dataclasses look their module up
_spec.loader.exec_module(_shm)
main = _shm.main

if __name__ == "__main__":
    sys.exit(main())
