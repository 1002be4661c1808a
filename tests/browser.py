"""A headless Chromium for the tests, driven through the DevTools protocol over a pipe
(``--remote-debugging-pipe``: JSON messages ending in a NUL byte on file descriptors 3
and 4; no network port, no client library).

``Browser.open(url, width, height)`` loads a page in a viewport of that size, waits until
its title says ``ready`` or ``error: ...`` and returns a :class:`Page`: the title, the
page's console messages and uncaught exceptions, and the screenshot (PNG bytes).
``find_browser()`` is the binary (``MI_PLUGINS_BROWSER``, else ``chromium``,
``chromium-browser``, ``google-chrome`` on the PATH) or None; ``.ci/ensure_browser.sh``
installs Debian's chromium.
"""
import base64
import json
import os
import select
import shutil
import subprocess
import sys
import tempfile
import time

NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-extensions", "--hide-scrollbars", "--enable-unsafe-swiftshader", "--remote-debugging-pipe")


#: the one browser warning that is no page error: software WebGL's note that the compositor
#: reads the canvas back (any page that draws with WebGL gets it, a clear alone included)
BENIGN = "GL Driver Message (OpenGL, Performance, GL_CLOSE_PATH_NV, High): GPU stall due to ReadPixels"


def find_browser():
    name = os.environ.get("MI_PLUGINS_BROWSER")
    if name:
        return shutil.which(name) or (name if os.path.isfile(name) else None)
    return next((shutil.which(n) for n in NAMES if shutil.which(n)), None)


class BrowserError(RuntimeError):
    pass


_TRAMPOLINE = """import fcntl, os, sys
a, b = (fcntl.fcntl(int(fd), fcntl.F_DUPFD, 10) for fd in sys.argv[1:3])
os.dup2(a, 3)
os.dup2(b, 4)
os.execvp(sys.argv[3], sys.argv[3:])
"""


class Page:
    """A loaded page: ``title``, ``errors`` (uncaught exceptions, console messages and
    browser log entries of level error or warning but ``BENIGN``, as text), ``messages``
    (every console message and log entry), ``png``."""

    def __init__(self, title, errors, messages, png):
        self.title, self.errors, self.messages, self.png = title, errors, messages, png

    @property
    def ok(self):
        return self.title == "ready" and not self.errors


class Browser:
    def __init__(self, binary, timeout=60.0):
        self.timeout = timeout
        self.profile = tempfile.mkdtemp(prefix="mi_plugins_browser_")
        to_browser, self._write = os.pipe()
        self._read, from_browser = os.pipe()
        # the browser's ends become its descriptors 3 and 4 (a small Python that moves them
        # there, then becomes the browser)
        command = [sys.executable, "-c", _TRAMPOLINE, str(to_browser), str(from_browser), binary,
                   "--user-data-dir=" + self.profile, *FLAGS, "about:blank"]
        self._log = open(os.path.join(self.profile, "browser.log"), "wb")
        self.process = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=self._log, stderr=self._log,
                                        pass_fds=(to_browser, from_browser))
        os.close(to_browser)
        os.close(from_browser)
        self._buffer, self._id, self.events = b"", 0, []
        try:
            target = self.call("Target.createTarget", url="about:blank")["targetId"]
            self.session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
            for domain in ("Runtime", "Log", "Page"):
                self.call(domain + ".enable", session=self.session)
        except (BrowserError, OSError) as e:
            log = self.log()
            self.close()
            raise BrowserError("the browser did not start (%s); its output:\n%s" % (e, log)) from e

    def log(self, lines=20):
        """The last ``lines`` of the browser's own output (not the pages' console)."""
        self._log.flush()
        with open(self._log.name, "rb") as f:
            return "\n".join(f.read().decode("utf-8", "replace").splitlines()[-lines:])

    # ------------------------------------------------------------------ the protocol
    def _message(self, deadline):
        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self._read], [], [], left)[0]:
                raise BrowserError("the browser did not answer within %.0f s" % self.timeout)
            chunk = os.read(self._read, 1 << 20)
            if not chunk:
                raise BrowserError("the browser closed its pipe (exit status %s)" % self.process.poll())
            self._buffer += chunk
        text, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(text)

    def call(self, method, session=None, **params):
        self._id += 1
        message = {"id": self._id, "method": method, "params": params}
        if session:
            message["sessionId"] = session
        os.write(self._write, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + self.timeout
        while True:
            reply = self._message(deadline)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise BrowserError("%s: %s" % (method, reply["error"]))
                return reply.get("result", {})
            if "method" in reply:
                self.events.append(reply)

    # ------------------------------------------------------------------ pages
    def open(self, url, width, height, timeout=None):
        """Load ``url`` in a ``width`` x ``height`` viewport; the :class:`Page` once its title
        starts with 'ready' or 'error' (or the timeout passed: the title as it is)."""
        s = self.session
        self.call("Emulation.setDeviceMetricsOverride", session=s, width=width, height=height,
                  deviceScaleFactor=1, mobile=False)
        self.call("Page.navigate", session=s, url="about:blank")
        self.events = []
        self.call("Page.navigate", session=s, url=url)
        deadline = time.monotonic() + (timeout or self.timeout)
        title = ""
        while time.monotonic() < deadline:
            title = self.call("Runtime.evaluate", session=s, expression="document.title",
                              returnByValue=True)["result"].get("value", "")
            if title == "ready" or title.startswith("error"):
                break
            time.sleep(0.05)
        png = base64.b64decode(self.call("Page.captureScreenshot", session=s, format="png")["data"])
        errors, messages = [], []
        for event in self.events:
            p = event.get("params", {})
            if event["method"] == "Runtime.exceptionThrown":
                d = p["exceptionDetails"]
                errors.append("exception: " + d.get("exception", {}).get("description", d.get("text", "")))
            elif event["method"] == "Runtime.consoleAPICalled":
                text = " ".join(str(a.get("value", a.get("description", ""))) for a in p.get("args", []))
                messages.append((p["type"], text))
                if p["type"] in ("error", "warning", "assert"):
                    errors.append("console.%s: %s" % (p["type"], text))
            elif event["method"] == "Log.entryAdded":
                entry = p["entry"]
                messages.append((entry["level"], entry["text"]))
                if entry["level"] == "error" or (entry["level"] == "warning" and BENIGN not in entry["text"]):
                    errors.append("log %s: %s" % (entry["level"], entry["text"]))
        return Page(title, errors, messages, png)

    # ------------------------------------------------------------------ input on the open page
    def screenshot(self):
        return base64.b64decode(self.call("Page.captureScreenshot", session=self.session, format="png")["data"])

    def evaluate(self, expression):
        return self.call("Runtime.evaluate", session=self.session, expression=expression,
                         returnByValue=True)["result"].get("value")

    def press(self, code, key, hold=0.0):
        """Key ``code`` (e.g. 'KeyW'; ``key``: its character, e.g. 'w') down, ``hold``
        seconds, up."""
        for kind in ("keyDown", "keyUp"):
            self.call("Input.dispatchKeyEvent", session=self.session, type=kind, code=code, key=key)
            if kind == "keyDown" and hold:
                time.sleep(hold)

    def drag(self, start, end, steps=4):
        """A left-button drag from ``start`` to ``end`` (CSS pixels)."""
        s = self.session
        self.call("Input.dispatchMouseEvent", session=s, type="mousePressed", x=start[0], y=start[1],
                  button="left", buttons=1, clickCount=1)
        for k in range(1, steps + 1):
            x, y = (start[i] + (end[i] - start[i]) * k / steps for i in (0, 1))
            self.call("Input.dispatchMouseEvent", session=s, type="mouseMoved", x=x, y=y, button="left", buttons=1)
        self.call("Input.dispatchMouseEvent", session=s, type="mouseReleased", x=end[0], y=end[1],
                  button="left", buttons=0, clickCount=1)

    def close(self):
        try:
            self.call("Browser.close")
        except (BrowserError, OSError):
            pass
        try:
            self.process.wait(10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        for fd in (self._read, self._write):
            os.close(fd)
        self._log.close()
        shutil.rmtree(self.profile, ignore_errors=True)
