"""``python -m doodlecam`` is the ``doodlecam`` command (and ``entry`` its console script)."""

import gc
import os
import sys

# The pipeline's matrix products are small ((n, 2) @ (2, 2)): BLAS threads would only spin,
# costing CPU time (measured: 13 s of a 36 s plan). doodlecam's parallelism is its own worker
# processes (convert --workers, batch --jobs). A user's setting is kept.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def entry() -> None:
    """Console-script entry point: Ctrl-C while the CLI is still being imported is one line too."""
    try:
        from doodlecam.cli import main
    except KeyboardInterrupt:
        sys.stderr.write("doodlecam: interrupted; no file was written\n")
        sys.exit(130)
    rc = main()
    # The process ends here. Python's shutdown runs full garbage collections over every object still alive
    # (numba's compiler state and ~1000 modules: ~0.25 s of CPU, a sixth of a small convert); nothing in them
    # is garbage the exit needs collected. Frozen objects are skipped by those collections and still freed
    # by reference counting as the modules are torn down; atexit handlers run as before.
    gc.freeze()
    sys.exit(rc)


if __name__ == "__main__":
    entry()
