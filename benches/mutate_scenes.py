#!/usr/bin/env python3
"""Careless-user scenes: mutates every bundled scene and example (numbers zeroed, negated, scaled
by 1e6 or 1e-6, made nan or inf; lines deleted; files cut short; body kinds changed, all bodies
fixed; tables duplicated or dropped; names swapped) and runs each variant through
`tensegrity check`, `statics --json` and a 0.05 s `deploy --dynamic`. Reports what no input may
cause: a panic, a command silent past 20 s, a null or non-finite number in the JSON or the CSV,
and a claimed equilibrium whose residual is above the convergence ceiling.

    cargo build --release
    python3 benches/mutate_scenes.py --variants 2500 [--jobs 2] [--bin target/release/tensegrity]

Exits 1 when any variant failed; the failing files are kept under --keep (default
target/mutated-failures) with the command and what went wrong. Not a test dependency: the
cases it found are tests (tests/degenerate_scenes.rs)."""

import argparse
import concurrent.futures
import glob
import json
import math
import os
import random
import re
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
NUMBER = re.compile(r"(?<![\w.])-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?(?![\w.])")
KINDS = ["fixed", "node", "bar", "rigid"]
SILENCE_S = 20.0
CEILING = 1e-6  # statics' ROUND_OFF_CEILING: no residual above this is ever called converged


def mutate(text, rng):
    """One careless edit of `text` (a scene file), and its description."""
    lines = text.split("\n")
    kind = rng.randrange(9)
    if kind == 0:
        spans = [m.span() for m in NUMBER.finditer(text)]
        if spans:
            a, b = rng.choice(spans)
            x = float(text[a:b])
            new = rng.choice(["0", "0.0", str(-x), repr(x * 1e6), repr(x * 1e-6), "nan", "inf", "-inf", "1e300", "-0.0"])
            return text[:a] + new + text[b:], f"number {text[a:b]!r} -> {new}"
    if kind == 1 and len(lines) > 1:
        i = rng.randrange(len(lines))
        return "\n".join(lines[:i] + lines[i + 1:]), f"line {i + 1} deleted"
    if kind == 2:
        i = rng.randrange(1, len(lines) + 1)
        return "\n".join(lines[:i]), f"cut after line {i}"
    if kind == 3:
        spans = [m.span(1) for m in re.finditer(r'kind = "(\w+)"', text)]
        if spans:
            a, b = rng.choice(spans)
            new = rng.choice(KINDS)
            return text[:a] + new + text[b:], f"a kind -> {new}"
    if kind == 4:
        fixed = re.sub(r'kind = "\w+"', 'kind = "fixed"', text)
        fixed = re.sub(r"\n(mass|inertia|ends|length|radius) = [^\n]*", "", fixed)
        return fixed, "every body fixed"
    headers = [i for i, l in enumerate(lines) if l.startswith("[")]
    if kind in (5, 6) and headers:
        i = rng.choice(headers)
        j = next((k for k in headers if k > i), len(lines))
        block = lines[i:j]
        if kind == 5:
            return "\n".join(lines[:j] + block + lines[j:]), f"table at line {i + 1} duplicated"
        return "\n".join(lines[:i] + lines[j:]), f"table at line {i + 1} dropped"
    if kind == 7:
        names = re.findall(r'name = "([^"]+)"', text)
        refs = [m.span(1) for m in re.finditer(r'"([\w.]+)"', text)]
        if names and refs:
            a, b = rng.choice(refs)
            new = rng.choice(names + ["", "nosuch", "nosuch.point"])
            return text[:a] + new + text[b:], f"string {text[a:b]!r} -> {new!r}"
    if kind == 8:
        spans = [m.span() for m in re.finditer(r"(?<=[=\[, ])\d+(?=[\],\n ])", text)]
        if spans:
            a, b = rng.choice(spans)
            new = rng.choice(["0", "1", "100000", "-1"])
            return text[:a] + new + text[b:], f"integer {text[a:b]} -> {new}"
    return text, "unchanged"


def run(cmd, cwd):
    """(exit code or 'silent', stdout, stderr)."""
    try:
        p = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=SILENCE_S)
        return p.returncode, p.stdout, p.stderr
    except subprocess.TimeoutExpired as e:
        out = (e.stdout or b"").decode(errors="replace") if isinstance(e.stdout, bytes) else (e.stdout or "")
        err = (e.stderr or b"").decode(errors="replace") if isinstance(e.stderr, bytes) else (e.stderr or "")
        return ("silent" if not (out or err) else "slow"), out, err


def non_finite(value, path="$"):
    """Paths of nulls and non-finite numbers in a parsed JSON value."""
    if value is None:
        return [path]
    if isinstance(value, float) and not math.isfinite(value):
        return [path]
    if isinstance(value, dict):
        return [p for k, v in value.items() for p in non_finite(v, f"{path}.{k}")]
    if isinstance(value, list):
        return [p for i, v in enumerate(value) for p in non_finite(v, f"{path}[{i}]")]
    return []


def problems(binary, path, workdir):
    """What went wrong for the scene file `path`: a list of (command, problem)."""
    found = []
    csv = os.path.join(workdir, "run.csv")
    commands = {
        "check": [binary, "check", path],
        "statics": [binary, "statics", path, "--json"],
        "deploy": [binary, "deploy", path, "--dynamic", "--duration", "0.05", "--out", csv],
    }
    for name, cmd in commands.items():
        if os.path.exists(csv):
            os.remove(csv)
        code, out, err = run(cmd, workdir)
        if code == "silent":
            found.append((name, f"no output for {SILENCE_S:.0f} s"))
            continue
        if "panicked" in err or code == 101 or (isinstance(code, int) and code < 0):
            found.append((name, "panic: " + (err.strip().splitlines() or ["(signal)"])[0][:300]))
            continue
        if name == "statics" and code == 0:
            try:
                report = json.loads(out, parse_constant=lambda c: float(c))
            except ValueError as e:
                found.append((name, f"not JSON: {e}"))
                continue
            bad = non_finite(report)
            if bad:
                found.append((name, f"null or non-finite numbers at {bad[:5]}"))
            residual, scale = report.get("residual_n"), report.get("force_scale_n")
            if report.get("stop_reason") == "converged" and isinstance(residual, float) and isinstance(scale, float):
                if residual > CEILING * scale * 1.0001:
                    found.append((name, f"converged with residual {residual:.3e} N at force scale {scale:.3e} N"))
        if name == "deploy" and code == 0 and os.path.exists(csv):
            with open(csv) as f:
                text = f.read()
            if re.search(r"(?i)(^|,)(nan|-?inf)(,|$)", text, re.M):
                found.append((name, "NaN or inf in the CSV"))
    return found


def variant_job(args):
    binary, source, seed = args
    rng = random.Random(seed)
    text = open(source).read()
    edits = []
    for _ in range(rng.choice([1, 1, 2, 3])):
        text, what = mutate(text, rng)
        edits.append(what)
    with tempfile.TemporaryDirectory() as work:
        path = os.path.join(work, os.path.basename(source))
        with open(path, "w") as f:
            f.write(text)
        found = problems(binary, path, work)
    return source, seed, edits, text, found


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variants", type=int, default=2500)
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 2)
    ap.add_argument("--bin", default=os.path.join(ROOT, "target/release/tensegrity"))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--keep", default=os.path.join(ROOT, "target/mutated-failures"))
    args = ap.parse_args()
    sources = sorted(glob.glob(os.path.join(ROOT, "config/scenes/*.toml")) + glob.glob(os.path.join(ROOT, "config/examples/*.toml")))
    jobs = [(os.path.abspath(args.bin), sources[i % len(sources)], args.seed * 1_000_003 + i) for i in range(args.variants)]
    failures = []
    with concurrent.futures.ThreadPoolExecutor(args.jobs) as pool:
        for k, (source, seed, edits, text, found) in enumerate(pool.map(variant_job, jobs), 1):
            if found:
                failures.append((source, seed, edits, text, found))
            if k % 250 == 0:
                print(f"{k}/{len(jobs)} variants, {len(failures)} failed", file=sys.stderr, flush=True)
    kinds = {}
    os.makedirs(args.keep, exist_ok=True)
    for source, seed, edits, text, found in failures:
        name = f"{os.path.splitext(os.path.basename(source))[0]}-{seed}.toml"
        with open(os.path.join(args.keep, name), "w") as f:
            f.write(f"# mutated from {os.path.relpath(source, ROOT)}: {'; '.join(edits)}\n")
            for cmd, what in found:
                f.write(f"# {cmd}: {what}\n")
            f.write(text)
        for cmd, what in found:
            key = f"{cmd}: {what.split(':')[0]}"
            kinds[key] = kinds.get(key, 0) + 1
    print(f"{len(jobs)} variants of {len(sources)} scenes, 3 commands each: {len(failures)} failed")
    for key, n in sorted(kinds.items(), key=lambda kv: -kv[1]):
        print(f"  {n:5d}  {key}")
    if failures:
        print(f"failing variants kept in {args.keep}")
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
