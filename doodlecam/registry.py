"""Finds plugins: entry points and drop-in folders, the same way for all.

Built-in plugins are registered through the same entry-point groups a third
party uses. A plugin that fails to import is reported by name; it never
breaks the CLI or the other plugins.
"""

from __future__ import annotations

import functools
import importlib.util
import inspect
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable

from doodlecam.errors import MachineError, PluginError, did_you_mean

if TYPE_CHECKING:
    from doodlecam.machine import Machine
    from doodlecam.options import ConvertOptions

GROUPS = {
    "tracer": "doodlecam.tracers",
    "machine": "doodlecam.machines",
    "postprocessor": "doodlecam.postprocessors",
    "transport": "doodlecam.transports",
}
PLUGIN_PATH_ENV = "DOODLECAM_PLUGIN_PATH"


@dataclass
class PluginInfo:
    kind: str
    name: str
    origin: str  # "entry point (dist x.y)" or a file path
    _load: Callable[[], type]
    _cls: type | None = None
    error: str | None = None

    def load(self) -> type:
        if self._cls is None:
            try:
                cls = self._load()
            except Exception as e:  # a broken plugin must not break us
                self.error = f"{type(e).__name__}: {e}"
                raise PluginError(f"{self.kind} plugin '{self.name}' ({self.origin}) failed to load: {self.error}") from None
            from doodlecam import api

            base = {"tracer": api.Tracer, "machine": api.Kinematics,
                    "postprocessor": api.PostProcessor, "transport": api.Transport}[self.kind]
            if not (inspect.isclass(cls) and issubclass(cls, base)):
                self.error = f"not a {base.__name__} subclass"
                raise PluginError(f"{self.kind} plugin '{self.name}' ({self.origin}) is {self.error}; fix the plugin")
            wants = getattr(cls, "api_version", api.API_VERSION)
            if not isinstance(wants, int) or not 1 <= wants <= api.API_VERSION:
                self.error = f"written for plugin API {wants!r}, this doodlecam has API {api.API_VERSION}"
                raise PluginError(f"{self.kind} plugin '{self.name}' ({self.origin}) is {self.error}; "
                                  "upgrade doodlecam or the plugin")
            self._cls = cls
        return self._cls

    @property
    def summary(self) -> str:
        try:
            return self.load().summary
        except PluginError:
            return f"BROKEN: {self.error}"


def _dropin_dirs(extra: Iterable[str | os.PathLike]) -> list[Path]:
    dirs = [Path(d) for d in extra]
    dirs += [Path(p) for p in os.environ.get(PLUGIN_PATH_ENV, "").split(os.pathsep) if p]
    for d in dirs:
        if not d.is_dir():
            raise PluginError(f"plugin folder {d} does not exist; check --plugin-dir / ${PLUGIN_PATH_ENV}")
    return dirs


def _import_file(path: Path):
    modname = f"doodlecam_dropin_{path.stem}"
    if modname in sys.modules:
        return sys.modules[modname]
    spec = importlib.util.spec_from_file_location(modname, path)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot import {path}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[modname] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[modname]
        raise
    return module


def _scan_file(path: Path) -> list[PluginInfo]:
    """A drop-in file: every plugin class defined in it (importing it once)."""
    from doodlecam import api

    try:
        module = _import_file(path)
    except Exception as e:
        err = f"{type(e).__name__}: {e}"

        def fail(err=err):
            raise ImportError(err)

        return [PluginInfo("?", path.stem, str(path), fail, error=err)]
    found = []
    for obj in vars(module).values():
        if (inspect.isclass(obj) and issubclass(obj, api.Plugin) and obj.__module__ == module.__name__
                and obj.name and obj.kind in GROUPS):
            found.append(PluginInfo(obj.kind, obj.name, str(path), lambda obj=obj: obj))
    return found


def _entry_points(group: str) -> tuple:
    """(name, origin, load) of a group's entry points."""
    return _all_entry_points().get(group, ())


@functools.lru_cache(maxsize=None)
def _all_entry_points() -> dict[str, tuple]:
    """_entry_points of every group, from one scan of the installed distributions (each scan reads every
    distribution's metadata: ~3-7 ms, and a convert asks all four groups); a batch worker looks plugins up
    for every file, and what is installed does not change while a process runs."""
    from importlib.metadata import entry_points

    every = entry_points()
    origins: dict[int, str] = {}  # by distribution: its name and version parse its whole METADATA file

    def origin(dist) -> str:
        if dist is None:
            return "entry point"
        if id(dist) not in origins:
            meta = dist.metadata  # what dist.name and dist.version read, parsed once
            origins[id(dist)] = f"entry point, {meta['Name']} {meta['Version']}"
        return origins[id(dist)]

    out = {}
    for group in GROUPS.values():
        eps = sorted(every.select(group=group), key=lambda e: e.name)
        out[group] = tuple((ep.name, origin(getattr(ep, "dist", None)), ep.load) for ep in eps)
    return out


def discover(plugin_dirs: Iterable[str | os.PathLike] = ()) -> list[PluginInfo]:
    """All plugins, drop-ins first (a drop-in overrides an entry point)."""
    infos: list[PluginInfo] = []
    for d in _dropin_dirs(plugin_dirs):
        for path in sorted(d.glob("*.py")):
            if not path.name.startswith("_"):
                infos.extend(_scan_file(path))
    seen = {(i.kind, i.name) for i in infos}
    for kind, group in GROUPS.items():
        for name, origin, load in _entry_points(group):
            if (kind, name) in seen:
                continue
            seen.add((kind, name))
            infos.append(PluginInfo(kind, name, origin, load))
    return infos


def _find(infos: list[PluginInfo], kind: str, name: str) -> PluginInfo | None:
    """The plugin of that kind named ``name`` exactly, else the one whose name differs only
    in case (``--post GCODE``)."""
    mine = [i for i in infos if i.kind == kind]
    for info in mine:
        if info.name == name:
            return info
    folded = [i for i in mine if i.name.casefold() == str(name).casefold()]
    return folded[0] if len(folded) == 1 else None


def canonical_name(kind: str, name: str, plugin_dirs: Iterable[str | os.PathLike] = ()) -> str:
    """The installed plugin's own spelling of ``name`` ('GCODE' -> 'gcode'); ``name`` itself when
    none matches (the checks then say what exists)."""
    try:
        info = _find(discover(plugin_dirs), kind, name)
    except PluginError:  # a missing --plugin-dir: reported by the checks
        return name
    return info.name if info is not None else name


def canonical_fields(options: "ConvertOptions") -> dict[str, Any]:
    """The plugin names of conversion options in the plugins' own spelling (tracer, posts, the
    posts of post_options): what differs, for the options' __post_init__ to set."""
    dirs = options.plugin_dirs
    posts = tuple(canonical_name("postprocessor", p, dirs) for p in options.posts)
    out: dict[str, Any] = {}
    if options.tracer:
        out["tracer"] = canonical_name("tracer", options.tracer, dirs)
    if posts != tuple(options.posts):
        out["posts"] = posts
    if options.post_options:
        fold = {p.casefold(): p for p in posts}
        out["post_options"] = {fold.get(k.casefold(), k): v for k, v in options.post_options.items()}
    return {k: v for k, v in out.items() if v != getattr(options, k)}


def get(kind: str, name: str, plugin_dirs: Iterable[str | os.PathLike] = ()) -> type:
    """The plugin class of that kind and name (any case), or a PluginError saying what exists."""
    infos = discover(plugin_dirs)
    info = _find(infos, kind, name)
    if info is not None:
        return info.load()
    names = sorted(i.name for i in infos if i.kind == kind)
    broken = [i for i in infos if i.kind == "?"]
    extra = f"; broken drop-ins: {', '.join(i.origin for i in broken)}" if broken else ""
    raise PluginError(f"unknown {kind} '{name}'{did_you_mean(name, names)}; available: "
                      f"{', '.join(names) or 'none'} (see 'doodlecam plugins'){extra}")


def kinematics_for(machine: "Machine", plugin_dirs=()):
    """The machine's kinematics plugin, built for its profile."""
    # exact: the profile's name is compared elsewhere too (a profile is fixed once, not typed each time)
    if not any(i.kind == "machine" and i.name == machine.kinematics for i in discover(plugin_dirs)):
        names = sorted(i.name for i in discover(plugin_dirs) if i.kind == "machine")
        raise MachineError(f"{machine.source or machine.name}: machine.kinematics = '{machine.kinematics}' is unknown"
                           f"{did_you_mean(machine.kinematics, names)}; use one of {', '.join(names)}, or give the "
                           "folder of its plugin with --plugin-dir")
    cls = get("machine", machine.kinematics, plugin_dirs)
    return cls(machine, machine.kinematics_params)
