"""A ``shipstar live`` subprocess for the live tests (test_live.py, test_console.py)."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time


class Live:
    """A ``shipstar live`` subprocess; its stderr collected in a thread."""

    def __init__(self, cwd, args):
        self.proc = subprocess.Popen([sys.executable, "-m", "shipstar", "live", *args], cwd=cwd,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.lines: list = []
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self):
        for line in self.proc.stderr:
            self.lines.append(line.rstrip("\n"))

    def wait_line(self, fragment, timeout_s=120.0):
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if any(fragment in line for line in self.lines):
                return True
            assert self.proc.poll() is None, "\n".join(self.lines)
            time.sleep(0.02)
        raise AssertionError(f"no line with {fragment!r}:\n" + "\n".join(self.lines))

    def stop(self, sig=signal.SIGTERM, timeout_s=60.0):
        """Send ``sig`` and wait: ``(exit code, stdout)``."""
        self.proc.send_signal(sig)
        out = self.proc.stdout.read()
        self.proc.wait(timeout_s)
        self._thread.join(5.0)
        self.proc.stdout.close()
        self.proc.stderr.close()
        return self.proc.returncode, out

    def interrupt(self, timeout_s=60.0) -> int:
        """SIGINT if still running (killed after ``timeout_s``): the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.communicate()
        self._thread.join(5.0)
        return self.proc.returncode
