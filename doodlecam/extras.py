"""The optional parts of doodlecam and the pip extras that install them.

``pip install doodlecam`` brings what ``convert``, ``batch`` and ``send`` need;
the rest comes with an extra (pyproject.toml's optional-dependencies, which
this table mirrors). A command that needs a missing one says, in one line,
which extra to install -- before it starts any work.
"""

from __future__ import annotations

from importlib.util import find_spec

from doodlecam.errors import DoodleError

# extra -> the modules doodlecam imports from it (tests/test_extras.py checks them against pyproject.toml)
EXTRAS: dict[str, tuple[str, ...]] = {
    "studio": ("fastapi", "uvicorn"),
    "plot": ("matplotlib",),
    "mesh": ("trimesh", "rtree"),
    "solvers": ("qpsolvers", "osqp", "highspy"),
    "dask": ("distributed",),
}


class MissingExtra(DoodleError):
    """A command needs an optional part that is not installed."""


def missing(extra: str) -> list[str]:
    """The modules of ``extra`` that cannot be imported here."""
    return [m for m in EXTRAS[extra] if find_spec(m) is None]


def require(extra: str, what: str, otherwise: str = "") -> None:
    """Raise MissingExtra (one line) unless every module of ``extra`` is installed; ``what`` is the
    subject of the sentence ("the studio"), ``otherwise`` an alternative ("or leave out --scheduler")."""
    if missing(extra):
        raise MissingExtra(f"{what} needs the {extra} extra: pip install 'doodlecam[{extra}]'"
                           + (f" ({otherwise})" if otherwise else ""))
