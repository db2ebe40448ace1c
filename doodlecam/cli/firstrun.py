"""The one-time notice that the first conversion after an install compiles the kernels.

The planner's and the fitter's hot loops are numba functions cached on disk
(``cache=True``): the first conversion after an install or an upgrade compiles
them, about a minute of CPU time, and every later run loads them in well under a
second. A wheel cannot run code at install time, so instead the user is told,
once per doodlecam/numba/Python version and install location. The marker
lives in the user cache folder (platformdirs; $XDG_CACHE_HOME on Linux).
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import click


def _marker() -> Path:
    from importlib.metadata import PackageNotFoundError, version

    from platformdirs import user_cache_dir

    import doodlecam

    try:
        numba = version("numba")
    except PackageNotFoundError:  # pragma: no cover - numba is a dependency
        numba = "?"
    key = f"{doodlecam.__version__}|{numba}|{sys.version}|{Path(doodlecam.__file__).resolve().parent}"
    return Path(user_cache_dir("doodlecam", appauthor=False)) / f"compiled-{hashlib.blake2b(key.encode(), digest_size=8).hexdigest()}"


def first_run_notice() -> None:
    """Say, once, that this run compiles; call it after every check passed, just before the work."""
    try:
        marker = _marker()
        if marker.exists():
            return
        pkg = Path(__file__).resolve().parent.parent
        # numba's cache next to the sources already holds the kernels: nothing to say
        if not all(any((pkg / sub / "__pycache__").glob("kernels.*.nbi")) for sub in ("plan", "geometry")):
            click.echo("doodlecam: first run of this install: compiling the planner's kernels (about a minute of CPU "
                       "time, once; later runs start at once)", err=True)
        marker.parent.mkdir(parents=True, exist_ok=True)
        marker.write_text("numba kernels compiled (cache=True) for this install\n")
    except OSError:  # no writable cache folder: the notice may repeat, the work does not suffer
        pass
