#!/usr/bin/env python3
"""Opens a viewer page in headless Chromium and records what happened, for tests/test_server_viewer.cpp.

usage: viewer_browser.py URL OUT_DIR [TIMEOUT_S]

Drives the browser over the DevTools protocol on a pipe (--remote-debugging-pipe: no port, no
extra package), with WebGL2 rendered in software by SwiftShader. Waits until the page says it is done
(body data-state "final": a material page drew its final frame; "listed": the listing is complete),
then writes to OUT_DIR:
  canvas.png    a material page's canvas, CSS pixel = screen pixel
  page.png      the whole window (docs/images/viewer_leather.png is one)
  record.json   {"events": window.viewerEvents, "requests": [{url, status, range, bytes}], "state", "log"}
bytes are the body bytes the browser received for a request (Network.dataReceived).
Exit status 0 when the page got there; otherwise 1 with one line on stderr saying why
(2: Chromium could not be started at all).
"""
import base64
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time


class Browser:
    def __init__(self, profile):
        exe = next((shutil.which(n) for n in ("chromium", "chromium-browser") if shutil.which(n)), None)
        if exe is None:
            raise OSError("no chromium on PATH (Debian package 'chromium', in the Makefile's DEB_PACKAGES)")
        to_browser_r, self.to_browser = os.pipe()
        self.from_browser, from_browser_w = os.pipe()

        def wire_pipes():  # the protocol's fds in the child: 3 = commands in, 4 = replies out
            # Through fresh copies: a pipe may itself be fd 3 or 4, and dup2 onto itself would keep
            # its close-on-exec flag.
            r, w = os.dup(to_browser_r), os.dup(from_browser_w)
            os.dup2(r, 3)
            os.dup2(w, 4)

        args = [exe, "--headless", "--no-sandbox", "--remote-debugging-pipe", f"--user-data-dir={profile}",
                "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
                "--force-color-profile=srgb", "--force-device-scale-factor=1", "--window-size=1100,800",
                "--no-first-run", "--no-default-browser-check", "--disable-extensions", "--mute-audio",
                "--disable-background-networking", "--disable-component-update", "--disable-sync", "about:blank"]
        self.log_path = os.path.join(profile, "chromium.log")
        self.log = open(self.log_path, "wb")
        self.proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=self.log, stderr=self.log,
                                     preexec_fn=wire_pipes, close_fds=False)
        os.close(to_browser_r)
        os.close(from_browser_w)
        self.buffer = b""
        self.next_id = 0
        self.events = []

    def send(self, method, params=None, session=None):
        self.next_id += 1
        message = {"id": self.next_id, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        os.write(self.to_browser, json.dumps(message).encode() + b"\0")
        while True:
            reply = self.read()
            if reply.get("id") == self.next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error'].get('message')}")
                return reply.get("result", {})
            self.events.append(reply)

    def read(self):
        while b"\0" not in self.buffer:
            chunk = os.read(self.from_browser, 1 << 16)
            if not chunk:
                raise EOFError("the browser closed its DevTools pipe")
            self.buffer += chunk
        message, self.buffer = self.buffer.split(b"\0", 1)
        return json.loads(message)

    def close(self):
        try:
            os.write(self.to_browser, json.dumps({"id": 0, "method": "Browser.close"}).encode() + b"\0")
            self.proc.wait(timeout=10)
        except Exception:
            self.proc.kill()
            self.proc.wait()


def requests_of(events):
    """Per request: url, status, Range header and body bytes received."""
    out = {}
    for e in events:
        p = e.get("params", {})
        rid = p.get("requestId")
        if e.get("method") == "Network.requestWillBeSent":
            out[rid] = {"url": p["request"]["url"], "range": p["request"].get("headers", {}).get("Range", ""),
                        "status": 0, "bytes": 0}
        elif rid in out and e.get("method") == "Network.responseReceived":
            out[rid]["status"] = p["response"]["status"]
        elif rid in out and e.get("method") == "Network.dataReceived":
            out[rid]["bytes"] += p["dataLength"]
    return list(out.values())


def main():
    url, out_dir = sys.argv[1], sys.argv[2]
    timeout = float(sys.argv[3]) if len(sys.argv) > 3 else 120
    profile = tempfile.mkdtemp(prefix="btfvq-chromium-")
    try:
        browser = Browser(profile)
        target = browser.send("Target.createTarget", {"url": "about:blank"})["targetId"]
    except Exception as e:  # one clear line: the test must not pass (or skip) without a browser
        log_path = os.path.join(profile, "chromium.log")
        log = open(log_path, "rb").read().decode(errors="replace").strip().splitlines() if os.path.exists(log_path) else []
        why = "it exited before answering on its DevTools pipe" if isinstance(e, (BrokenPipeError, EOFError)) else e
        print(f"chromium cannot start: {why}{' (last line of its log: ' + log[-1] + ')' if log else ''}", file=sys.stderr)
        shutil.rmtree(profile, ignore_errors=True)
        return 2
    try:
        session = browser.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        for domain in ("Network", "Page", "Runtime"):
            browser.send(f"{domain}.enable", session=session)
        browser.send("Network.setCacheDisabled", {"cacheDisabled": True}, session=session)
        browser.send("Page.navigate", {"url": url}, session=session)

        def evaluate(expression):
            r = browser.send("Runtime.evaluate", {"expression": expression, "returnByValue": True}, session=session)
            return r.get("result", {}).get("value")

        deadline, state = time.time() + timeout, None
        while time.time() < deadline:
            state = evaluate("document.body ? document.body.dataset.state || '' : ''")
            if state in ("final", "listed", "error"):
                break
            time.sleep(0.1)
        record = {"state": state, "events": json.loads(evaluate("JSON.stringify(window.viewerEvents || [])") or "[]"),
                  "page_text": evaluate("document.body ? document.body.innerText : ''")}
        if state in ("final", "listed"):
            page = browser.send("Page.captureScreenshot", {"format": "png"}, session=session)
            with open(os.path.join(out_dir, "page.png"), "wb") as f:
                f.write(base64.b64decode(page["data"]))
        if state == "final":
            box = evaluate("(() => { const r = document.getElementById('canvas').getBoundingClientRect();"
                           " return [r.left, r.top, r.width, r.height]; })()")
            shot = browser.send("Page.captureScreenshot", {"format": "png", "clip": {
                "x": box[0], "y": box[1], "width": box[2], "height": box[3], "scale": 1}}, session=session)
            with open(os.path.join(out_dir, "canvas.png"), "wb") as f:
                f.write(base64.b64decode(shot["data"]))
        # Network events still queued on the pipe belong to this page too.
        browser.send("Runtime.evaluate", {"expression": "0"}, session=session)
        record["requests"] = requests_of(browser.events)
        with open(os.path.join(out_dir, "record.json"), "w") as f:
            json.dump(record, f, indent=1)
        if state not in ("final", "listed"):
            errors = [e.get("message") for e in record["events"] if e.get("type") == "error"]
            print(f"the viewer page did not finish (state {state!r}): {errors or record['page_text']}",
                  file=sys.stderr)
            return 1
        return 0
    finally:
        browser.close()
        shutil.rmtree(profile, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
