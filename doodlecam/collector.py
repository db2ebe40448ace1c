"""Python's cyclic garbage collector around the pipeline's allocation-heavy stretches.

While the collector is off, every object allocated and still alive stays in its youngest generation, so the
first young collection after it is on again walks all of them (after a 20 000-path convert: ~10^6 objects,
0.1 s), although they are the job and the parsed drawing, alive or garbage only as a whole later. Turning it
on again promotes them to the oldest generation first, as if they had survived young collections, so only a
full collection walks them again.
"""

from __future__ import annotations

import contextlib
import gc


def enable_promoted() -> None:
    """Turn the collector on, the objects allocated while it was off promoted to the oldest generation
    (gc.freeze then gc.unfreeze: two list splices, no walk). A caller's own frozen objects are left alone:
    then no promotion."""
    if gc.get_freeze_count() == 0:
        gc.freeze()
        gc.unfreeze()
    gc.enable()


@contextlib.contextmanager
def no_collections():
    """No cyclic collections inside; the collector's state restored after (promoted: enable_promoted)."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            enable_promoted()
