"""``python -m doodlecam`` is the ``doodlecam`` command (and ``entry`` its console script)."""

import sys


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
