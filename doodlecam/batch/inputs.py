"""Finding the inputs of a batch and naming their outputs.
"""

from __future__ import annotations

import fnmatch
import hashlib
import os
from pathlib import Path
from typing import Iterable

from doodlecam.errors import DoodleError, InputError

# ---------------------------------------------------------------- finding inputs


def supported_extensions(tracer: str | None = None, plugin_dirs: Iterable[str] = ()) -> set[str]:
    """File extensions (lower case, with the dot) some tracer reads; the named one's only if given."""
    from doodlecam import registry

    if tracer:
        return set(registry.get("tracer", tracer, plugin_dirs).extensions)
    exts: set[str] = set()
    for info in registry.discover(plugin_dirs):
        if info.kind == "tracer":
            try:
                exts |= set(info.load().extensions)
            except DoodleError:
                continue
    return exts


def check_posts(posts: Iterable[str], plugin_dirs: Iterable[str] = ()) -> None:
    """A misspelt post is one error now, not one per file (names only: loading stays in the workers)."""
    from doodlecam import registry

    known = {i.name for i in registry.discover(plugin_dirs) if i.kind == "postprocessor"}
    for post in posts:
        if post not in known:
            registry.get("postprocessor", post, plugin_dirs)  # raises the usual "unknown ...; available: ..."


def nothing_to_convert(in_dir: Path, out_dir: Path, recursive: bool, filtered: bool,
                       unsupported: list[str]) -> InputError:
    """The one-line error for a folder with no file to convert, saying what to try."""
    where = " matching --include/--exclude" if filtered else ""
    if unsupported:
        types = sorted({Path(u).suffix.lower() or "(no extension)" for u in unsupported})
        found = (f"only {len(unsupported)} file{'s' if len(unsupported) != 1 else ''}{where}, of types no tracer reads "
                 f"({', '.join(types[:4])}{', ...' if len(types) > 4 else ''})")
    else:
        found = f"no files{where}"
    hints = []
    out_res = out_dir.resolve()
    if not recursive and any(p.is_dir() and not p.name.startswith(".") and p.resolve() != out_res
                             for p in in_dir.iterdir()):
        hints.append("add -r to convert sub-folders")
    if filtered:
        hints.append("loosen --include/--exclude")
    hints.append("put pictures there ('doodlecam plugins' lists the file types)")
    return InputError(f"{in_dir}: nothing to convert, {found}; " + " or ".join(hints))


def _matches(rel: str, patterns: Iterable[str]) -> bool:
    name = rel.rsplit("/", 1)[-1]
    return any(fnmatch.fnmatchcase(rel, p) or ("/" not in p and fnmatch.fnmatchcase(name, p)) for p in patterns)


def find_inputs(in_dir: Path, out_dir: Path | None = None, recursive: bool = False,
                include: Iterable[str] = (), exclude: Iterable[str] = (),
                extensions: set[str] = frozenset()) -> tuple[list[str], list[str]]:
    """(supported, unsupported) input paths relative to ``in_dir`` (POSIX style, sorted).

    Hidden files and folders (a leading dot) and the output folder are skipped.
    ``include``/``exclude`` are globs matched against the relative path, and
    against the file name when the pattern has no ``/``.
    """
    include, exclude = tuple(include), tuple(exclude)
    out_res = out_dir.resolve() if out_dir is not None else None
    supported, unsupported = [], []
    for root, dirs, files in os.walk(in_dir):
        rootp = Path(root)
        if not recursive:
            dirs[:] = []
        else:
            dirs[:] = sorted(d for d in dirs if not d.startswith(".") and (rootp / d).resolve() != out_res)
        for f in files:
            if f.startswith("."):
                continue
            rel = (rootp / f).relative_to(in_dir).as_posix()
            if include and not _matches(rel, include):
                continue
            if exclude and _matches(rel, exclude):
                continue
            (supported if Path(f).suffix.lower() in extensions else unsupported).append(rel)
    return sorted(supported), sorted(unsupported)


def output_stems(rels: list[str]) -> dict[str, str]:
    """Output path stem (relative, POSIX) per input: ``sub/a.png`` -> ``sub/a``.

    Two inputs that would share a stem in one folder (``a.png`` and ``a.jpg``)
    both get their extension in the name instead (``a_png``, ``a_jpg``), so names
    stay deterministic and nothing is overwritten.
    """
    def plain(rel):
        p = Path(rel)
        return (p.parent / p.stem).as_posix()

    counts: dict[str, int] = {}
    for rel in rels:
        k = plain(rel).lower()
        counts[k] = counts.get(k, 0) + 1
    out = {}
    for rel in rels:
        p = Path(rel)
        out[rel] = plain(rel) if counts[plain(rel).lower()] == 1 else (p.parent / (p.stem + "_" + p.suffix[1:])).as_posix()
    return out


def file_hash(path: Path) -> str:
    h = hashlib.blake2b(digest_size=16)
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
