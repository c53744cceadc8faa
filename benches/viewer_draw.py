#!/usr/bin/env python3
"""How long the viewer's page takes to draw a frame, in a real browser on this machine.

Starts `tensegrity view TARGET --port 0`, opens its page in Debian's headless Chromium (real
time, no virtual clock) playing, and after `--seconds` reads the page's moving average of a
draw's wall time (`#scene-graph` data `drawMs`, kept by viewer.js) and the frames it drew,
through the DevTools protocol. Prints one Markdown row.

Usage (after `cargo build --release`; needs `pip install websocket-client`):
    python3 benches/viewer_draw.py TARGET [--seconds 8]
e.g. a 256-stage tower's bag:
    target/release/tensegrity generate tower --stages 256 --out /tmp/tower256.toml
    target/release/tensegrity deploy /tmp/tower256.toml --dynamic --duration 1 --out /tmp/t.csv --record /tmp/towerbag
    python3 benches/viewer_draw.py /tmp/towerbag
"""

import argparse
import json
import os
import subprocess
import tempfile
import time
import urllib.request

import websocket  # websocket-client

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("target")
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--port", type=int, default=9333, help="the browser's DevTools port")
    args = ap.parse_args()
    view = subprocess.Popen([os.path.join(ROOT, "target", "release", "tensegrity"), "view", args.target,
                             "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    url = None
    while url is None:
        line = view.stdout.readline()
        if not line:
            raise SystemExit("the viewer did not start")
        if "http://127.0.0.1:" in line:
            url = line.split()[2]
    browser = subprocess.Popen(
        ["chromium", "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         f"--user-data-dir={tempfile.mkdtemp()}", "--window-size=1000,640",
         f"--remote-debugging-port={args.port}", f"--remote-allow-origins=http://127.0.0.1:{args.port}",
         url + "?speed=1"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        for _ in range(100):
            try:
                pages = json.load(urllib.request.urlopen(f"http://127.0.0.1:{args.port}/json", timeout=2))
                page = next(p for p in pages if p.get("type") == "page")
                break
            except Exception:
                time.sleep(0.2)
        time.sleep(args.seconds)
        ws = websocket.create_connection(page["webSocketDebuggerUrl"], timeout=10)
        ws.send(json.dumps({"id": 1, "method": "Runtime.evaluate",
                            "params": {"expression": "JSON.stringify(window.tensegrityView)"}}))
        view_state = json.loads(json.loads(ws.recv())["result"]["result"]["value"])
        ws.close()
    finally:
        browser.terminate()
        view.terminate()
    print("| target | struts | cables | draws in {:g} s | a draw, ms (moving average) |".format(args.seconds))
    print("| --- | ---: | ---: | ---: | ---: |")
    print(f"| {args.target} | {view_state['struts']} | {view_state['cables']} | {view_state['draws']} | "
          f"{view_state['drawMs']} |")


if __name__ == "__main__":
    main()
