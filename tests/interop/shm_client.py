"""The shared-memory client's command line (`--check`, `--bench`, `--sizes`): the Python test
kit's `tensegrity_testing.shm` (in python/ of this repository, also installable with
`pip install ./python`), run from a checkout without installing it."""

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2] / "python"))

from tensegrity_testing.shm import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
