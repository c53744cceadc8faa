#!/usr/bin/env python3
"""What a live viewer costs the node it watches.

One `tensegrity_node` steps the six-bar robot (config/scenes/sixbar.toml: its schedule's haul, then
at rest) as fast as it can (`real_time_factor` 0) over shared memory only, pinned to core 0. A
probe viewer (`tensegrity view node`, pinned to core 1) follows it throughout and reads its step
count from the page's data. In alternating windows of `--seconds` each, `--rounds` times, a
second viewer (also on core 1) follows the node too, or does not. The node's steps per second of
wall time in each kind of window give its step time with one viewer and with two: their
difference is what one more live viewer costs the node. Prints medians and the ratio as a
Markdown table.

Usage (after `cargo build --release`):
    python3 benches/viewer_cost.py [--rounds 5] [--seconds 8]
Shared memory only: the node opens no DDS socket, so no network namespace is needed.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
import urllib.request

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def newest_step(url):
    with urllib.request.urlopen(url + "frames?from=0&max=1", timeout=5) as r:
        first = json.load(r)
    with urllib.request.urlopen(url + f"frames?from={first['next'] - 1}", timeout=5) as r:
        d = json.load(r)
    return d["frames"][-1]["step"]


def viewer(release, prefix, scene):
    v = subprocess.Popen(
        ["taskset", "-c", "1", os.path.join(release, "tensegrity"), "view", f"node:{prefix}", "--scene", scene,
         "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    for _ in range(2):
        line = v.stdout.readline()
    return v, line.split()[2]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--seconds", type=float, default=8.0)
    args = ap.parse_args()
    release = os.path.join(ROOT, "target", "release")
    prefix = f"viewer_cost_{os.getpid()}"
    scene = os.path.join(ROOT, "config", "scenes", "sixbar.toml")
    node = subprocess.Popen(
        ["taskset", "-c", "0", os.path.join(release, "tensegrity_node"), scene, "--ros-args",
         "-p", "transports:=shm", "-p", f"shm_prefix:={prefix}", "-p", "follow_schedule:=true",
         "-p", "real_time_factor:=0"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(1.0)
    probe, url = viewer(release, prefix, scene)
    time.sleep(3.0)
    one, two = [], []
    try:
        for _ in range(args.rounds):
            for second in (False, True):
                extra = viewer(release, prefix, scene)[0] if second else None
                time.sleep(0.5)
                s0, w0 = newest_step(url), time.monotonic()
                time.sleep(args.seconds)
                s1, w1 = newest_step(url), time.monotonic()
                us = 1e6 * (w1 - w0) / (s1 - s0)
                (two if second else one).append(us)
                if extra:
                    extra.terminate()
                    extra.wait()
                print(f"  {'two viewers' if second else 'one viewer '}: {us:.3f} us a step", file=sys.stderr)
    finally:
        probe.terminate()
        node.terminate()
        node.wait()
    a, b = statistics.median(one), statistics.median(two)
    print("| node's step, one viewer | with a second viewer | ratio |")
    print("| ---: | ---: | ---: |")
    print(f"| {a:.3f} us | {b:.3f} us | {b / a:.4f} |")
    print(f"medians of {args.rounds} alternating windows of {args.seconds:g} s; six-bar, as fast as it "
          "can step (its schedule's haul, then at rest), shared memory only, node on core 0, viewers on core 1",
          file=sys.stderr)


if __name__ == "__main__":
    main()
