"""Child process of the kill test (test_nothing_lost.py): saves two versions of each output,
alternately, over and over, until it is killed.

    python save_loop.py DIRECTORY

Prints "ready" once every output exists (a complete first round), then keeps overwriting.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from stress_kit import output_versions  # noqa: E402


def main() -> None:
    directory = Path(sys.argv[1])
    versions = [output_versions(0), output_versions(1)]
    round_ = 0
    while True:
        for name, (save, _) in versions[round_ % 2].items():
            save(directory / name)
        if round_ == 0:
            print("ready", flush=True)
        round_ += 1


if __name__ == "__main__":
    main()
