#!/usr/bin/env python3
"""Statics and quasi-static deployment of scenes without stick-slip ground friction, on two
builds: their outputs compared byte for byte, and the wall time of `statics` (the whole process,
median of interleaved runs). Shows that friction in statics costs the scenes that do not declare
it nothing.

Usage (BASE a build of the commit before the change, e.g. 7897d4f):
    git worktree add /tmp/base 7897d4f
    CARGO_TARGET_DIR=target/base cargo build --release --bin tensegrity --manifest-path /tmp/base/Cargo.toml
    cargo build --release --bin tensegrity
    taskset -c 0 python3 benches/friction_free_statics.py target/base/release/tensegrity target/release/tensegrity
"""
import statistics
import subprocess
import sys
import time

SCENES = [
    "config/scenes/prism3.toml",
    "config/scenes/tbar.toml",
    "config/examples/truss.toml",
    "config/scenes/tower.toml",
    "config/examples/sled.toml",
    "config/examples/collision.toml",
    "config/examples/hoist.toml",
    "config/examples/ground.toml",  # a ground with the regularized law
]
ROUNDS = 15


def outputs(binary, scene):
    statics = subprocess.run([binary, "statics", scene, "--json"], capture_output=True).stdout
    path = subprocess.run([binary, "deploy", "--quasi-static", scene, "--out", "-"], capture_output=True).stdout
    return statics, path


def timed(binary, scene):
    start = time.perf_counter()
    subprocess.run([binary, "statics", scene], stdout=subprocess.DEVNULL, check=True)
    return time.perf_counter() - start


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    base, new = sys.argv[1:]
    print("| scene | statics and path outputs | base ms | new ms | new / base |")
    print("| --- | --- | ---: | ---: | ---: |")
    for scene in SCENES:
        same = "identical" if outputs(base, scene) == outputs(new, scene) else "DIFFERENT"
        times = {base: [], new: []}
        for _ in range(ROUNDS):
            for binary in (base, new):
                times[binary].append(timed(binary, scene))
        b, n = statistics.median(times[base]), statistics.median(times[new])
        print(f"| `{scene}` | {same} | {b * 1e3:.2f} | {n * 1e3:.2f} | {n / b:.3f} |")


if __name__ == "__main__":
    main()
