"""Every mistake a user can make in a command line or a profile, found before any work.

``convert``, ``batch`` and the Python API call :func:`check_settings` first: a
misspelt plugin, an unknown option of a plugin that will run, a misspelt
plugin section in the profile (``[post.gcod]``), an unwritable output folder
or an unreachable scheduler each end in one line (a DoodleError, exit 2)
before a picture is traced, and before anything is written.
"""

from __future__ import annotations

import os
import socket
import tempfile
from pathlib import Path
from typing import Iterable

from doodlecam import registry
from doodlecam.errors import DoodleError, InputError, MachineError, OutputError, PluginError, did_you_mean
from doodlecam.extras import require
from doodlecam.machine import Machine
from doodlecam.options import ConvertOptions, layout_options, order_options

# profile table -> registry kind
SECTION_KINDS = {"trace": "tracer", "post": "postprocessor", "transport": "transport"}


def check_profile_plugins(machine: Machine, plugin_dirs: Iterable[str] = ()) -> None:
    """Every ``[trace.X]``, ``[post.X]`` and ``[transport.X]`` table of the profile names an
    installed plugin and only its options (each coerced to its type): a misspelt
    section would otherwise be ignored silently and the job run with the defaults."""
    infos = registry.discover(plugin_dirs)
    for section, values in machine.plugin_options.items():
        group, _, name = section.partition(".")
        kind = SECTION_KINDS[group]
        names = sorted(i.name for i in infos if i.kind == kind)
        if name not in names:
            raise MachineError(f"{machine.source}: [{section}] names no {kind}{did_you_mean(name, names)}; "
                               f"rename it to one of: {', '.join(f'[{group}.{n}]' for n in names) or 'none'}")
        try:
            registry.get(kind, name, plugin_dirs).resolve_options(values)
        except PluginError as e:
            raise MachineError(f"{machine.source}: [{section}]: {e}") from None


def pick_tracer(path: Path, tracer: str | None, plugin_dirs: Iterable[str] = ()) -> type:
    """The tracer named, else the first one that reads this file type (for pictures ``auto``:
    centre lines for line art, else the report's ``edges``)."""
    if tracer:
        return registry.get("tracer", tracer, plugin_dirs)
    ext = path.suffix.lower()
    candidates = [i for i in registry.discover(plugin_dirs) if i.kind == "tracer"]
    candidates.sort(key=lambda i: (i.name != "auto", i.name != "edges"))
    for info in candidates:
        try:
            cls = info.load()
        except PluginError:
            continue
        if ext in cls.extensions:
            return cls
    raise InputError(f"{path}: no tracer reads '{ext or 'files without extension'}' files; "
                     "give a picture (PNG, JPEG, ...) or pick one with --tracer")


def check_layer(layer: str, tracer: type, resolved: dict, ext: str) -> None:
    """``--layer`` names a layer the tracer can draw, when it can tell before tracing (a picture's
    edges are one layer: only the file's own layers, in an SVG or DXF, can be picked)."""
    names = tracer.layer_names(resolved)
    if names is None or layer in names:
        return
    files = f"{ext or 'such'} files" if ext else "its input"
    if not names:
        raise InputError(f"--layer {layer!r}: the {tracer.name} tracer draws {files} as one layer; layers come from "
                         "SVG and DXF files (or --tracer hatch --tracer-opt layers=tone: 'tone 1', 'tone 2', ...); "
                         "leave --layer out")
    raise InputError(f"--layer {layer!r}: the {tracer.name} tracer draws the layers "
                     f"{', '.join(repr(n) for n in names)}; pick one of them")


def check_output_dir(outdir: Path) -> None:
    """``outdir`` is, or can be made, a writable folder; nothing is left behind by the check."""
    outdir = Path(outdir)
    probe = outdir
    while not probe.exists():  # the nearest existing ancestor is where the folders will be made
        if probe.parent == probe:
            break
        probe = probe.parent
    if not probe.is_dir():
        raise OutputError(f"{outdir}: {probe} is a file, not a folder; choose another output folder (-o)")
    try:  # a real write, not os.access: read-only mounts and root both answer honestly
        with tempfile.TemporaryFile(dir=probe, prefix=".doodlecam-probe-"):
            pass
    except OSError as e:
        raise OutputError(f"{outdir}: cannot write in {probe} ({e.strerror}); choose another output folder (-o) "
                          "or fix its permissions") from None


def check_scheduler(address: str, timeout: float = 3.0) -> None:
    """A Dask scheduler address has a host and a port and something listens there."""
    from urllib.parse import urlsplit

    require("dask", "--scheduler")
    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme not in ("tcp", "tls") or not parts.hostname or port is None:
        raise DoodleError(f"--scheduler {address}: give the Dask scheduler's address as tcp://HOST:PORT "
                          "(e.g. tcp://10.0.0.5:8786)")
    try:
        sock = socket.create_connection((parts.hostname, port), timeout=timeout)
    except OSError as e:
        raise DoodleError(f"--scheduler {address}: cannot reach it ({e.strerror or e}); start the scheduler "
                          "('dask scheduler') or check the address") from None
    with sock:
        # A Dask scheduler sends its handshake as soon as it accepts (distributed.comm); a peer that
        # stays mute would make distributed.Client wait forever, whatever its timeout.
        if parts.scheme == "tcp":
            try:
                sock.settimeout(timeout)
                greeting = sock.recv(1)
            except OSError:
                greeting = b""
            if not greeting:
                raise DoodleError(f"--scheduler {address}: something listens there but no Dask scheduler answers "
                                  f"within {timeout:g} s; check the address and port") from None


def check_pens(machine: Machine, kin) -> None:
    """A pen's max_accel caps the paper's x and y accelerations: only a machine whose axes are
    the paper's axes (a diagonal linear map) can keep it exactly."""
    import numpy as np

    if not any(p.max_accel is not None for p in (machine.pens or (machine.pen,))):
        return
    M = None if kin.linear_map is None else np.asarray(kin.linear_map, float)
    if M is None or np.count_nonzero(M - np.diag(np.diag(M))):
        raise MachineError(f"{machine.source or machine.name}: a pen's max_accel needs a machine whose axes are the "
                           f"paper's x and y; the {machine.kinematics} machine cannot keep it: use max_speed for that pen")


def check_settings(options: ConvertOptions, machine: Machine, inputs: Iterable[Path] = (),
                   outdir: Path | None = None) -> dict[str, type]:
    """Check everything a conversion will use, cheaply, before any work.

    ``inputs``: the files to convert (one tracer is picked per file type).
    Returns the tracer class for each file extension. Raises a DoodleError.
    """
    from doodlecam.plan.planner import check_solver

    dirs = tuple(options.plugin_dirs)
    check_profile_plugins(machine, dirs)
    tracers: dict[str, type] = {}
    for path in inputs:
        ext = Path(path).suffix.lower()
        if ext not in tracers:
            tracers[ext] = pick_tracer(Path(path), options.tracer, dirs)
    if options.tracer and not tracers:
        tracers[""] = registry.get("tracer", options.tracer, dirs)
    for ext, cls in tracers.items():
        cls.check_extension(ext)
        resolved = cls.resolve_options(machine.plugin_options.get(f"trace.{cls.name}", {}), options.tracer_options)
        cls.check_options(resolved, machine.pen.width)
        if options.layer is not None:
            check_layer(options.layer, cls, resolved, ext)
    posts = {post: registry.get("postprocessor", post, dirs) for post in options.posts}
    for post, cls in posts.items():
        cls.resolve_options(machine.plugin_options.get(f"post.{post}", {}), options.post_options.get(post, {}))
    unused = set(options.post_options) - set(options.posts)
    if unused:
        name = sorted(unused)[0]
        raise PluginError(f"options given for post '{name}'{did_you_mean(name, options.posts)}, which is not among the "
                          f"posts {', '.join(options.posts)}")
    check_pens(machine, registry.kinematics_for(machine, dirs))
    check_solver(options.solver or machine.solver)
    layout_options({**machine.layout, **options.layout})
    order_options({**machine.order, **options.order})
    if outdir is not None:
        check_output_dir(outdir)
        for path in inputs:  # `x.svg -o .` with the svg post would write over the input
            for post, cls in posts.items():
                if (Path(outdir) / f"{Path(path).stem}{cls.extension}").resolve() == Path(path).resolve():
                    raise InputError(f"{path}: the {post} post would replace the input with {Path(path).name}; "
                                     "choose another output folder with -o")
    return tracers


def check_input(path: Path) -> None:
    """``path`` is a file that can be read (one conversion's input)."""
    if not path.exists():
        raise InputError(f"{path}: no such file; check the path")
    if path.is_dir():
        raise InputError(f"{path}: is a folder; give one file (folders are for 'doodlecam batch')")
    if not os.access(path, os.R_OK):
        raise InputError(f"{path}: cannot read it; check its permissions")

