"""``python -m doodlecam`` is the ``doodlecam`` command (and ``entry`` its console script)."""

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
    sys.exit(main())


if __name__ == "__main__":
    entry()
