"""Headless Chromium for checking HTML output: find the browser, screenshot a page, dump the
DOM a page's scripts leave (Debian's ``chromium``; absent: ``find_chromium`` returns None and
the callers skip with that reason).

Every call runs in a fresh temporary profile, with the network features a headless check does
not need switched off, and is bounded in time: a page that never settles is a failed check, not
a hang.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "chrome")
"""Executable names tried in order (Debian, Ubuntu, Google's builds)."""

CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
)

NO_CHROMIUM = "no headless Chromium (apt-get install -y chromium)"
"""The reason a check that needs the browser gives when it skips."""


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome executable, or None."""
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


def _run(chromium: str, args: list[str], timeout_s: float) -> subprocess.CompletedProcess | None:
    with tempfile.TemporaryDirectory(prefix="pcvfe_chromium_") as profile:
        cmd = [chromium, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", *args]
        try:
            return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
        except subprocess.TimeoutExpired:
            return None


def screenshot(
    chromium: str,
    page: Path,
    png: Path,
    size: tuple[int, int] = (1280, 800),
    wait_ms: int = 10000,
    timeout_s: float = 120.0,
) -> bool:
    """Screenshot ``page`` (an HTML file) into ``png`` at ``size`` (width, height) [px] after
    ``wait_ms`` of virtual time for its scripts; True when a non-empty image was written."""
    _run(
        chromium,
        [
            f"--window-size={size[0]},{size[1]}",
            f"--virtual-time-budget={wait_ms}",
            f"--screenshot={png}",
            Path(page).resolve().as_uri(),
        ],
        timeout_s,
    )
    return png.is_file() and png.stat().st_size > 0


def dump_dom(chromium: str, page: Path, wait_ms: int = 5000, timeout_s: float = 90.0) -> str:
    """The DOM of ``page`` after ``wait_ms`` of virtual time (what its scripts wrote); empty
    when the browser failed or timed out."""
    done = _run(
        chromium,
        [f"--virtual-time-budget={wait_ms}", "--dump-dom", Path(page).resolve().as_uri()],
        timeout_s,
    )
    return done.stdout if done is not None else ""
