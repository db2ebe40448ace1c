"""``doodlecam plugins`` (list) and ``doodlecam plugins show NAME`` (one plugin's options)."""

from __future__ import annotations

import inspect as _inspect

import click

from doodlecam.cli import complete

from doodlecam.errors import PluginError

PLUGIN_DIR = click.option("--plugin-dir", "plugin_dirs", multiple=True, type=click.Path(file_okay=False),
                          help="Folder of drop-in plugin .py files (repeatable; also $DOODLECAM_PLUGIN_PATH).")

KINDS = {"tracer": "Tracers", "machine": "Machines (kinematics)", "postprocessor": "Post-processors",
         "transport": "Transports", "?": "Broken drop-ins"}
# How each kind's options are set: (CLI flag, profile table prefix).
SETTING = {"tracer": ("--tracer-opt KEY=VALUE", "trace"), "postprocessor": ("--post-opt {name}.KEY=VALUE", "post"),
           "machine": (None, None), "transport": (None, None)}


@click.group(invoke_without_command=True)
@PLUGIN_DIR
@click.pass_context
def plugins(ctx, plugin_dirs):
    """List tracer, machine, post-processor and transport plugins.

    \b
    doodlecam plugins               every plugin, its summary and origin
    doodlecam plugins show gcode    one plugin: origin, options (type, default, help)
    """
    ctx.ensure_object(dict)["plugin_dirs"] = tuple(plugin_dirs)
    if ctx.invoked_subcommand is not None:
        return
    from doodlecam.registry import discover

    infos = discover(plugin_dirs)
    for kind, title in KINDS.items():
        rows = [i for i in infos if i.kind == kind]
        if not rows:
            continue
        click.echo(f"{title}:")
        for i in rows:
            summary = i.summary if kind != "?" else f"BROKEN: {i.error}"
            click.echo(f"  {i.name:<12} {summary}  [{i.origin}]")
    click.echo("Details and options of one plugin: doodlecam plugins show NAME")


def _fmt(value) -> str:
    return repr(value) if isinstance(value, str) else str(value).lower() if isinstance(value, bool) else str(value)


@plugins.command()
@click.argument("name", shell_complete=complete.plugins)
@click.option("--kind", type=click.Choice(["tracer", "machine", "postprocessor", "transport"]),
              help="Which kind, when several plugins share NAME.")
@PLUGIN_DIR
@click.pass_context
def show(ctx, name, kind, plugin_dirs):
    """Print one plugin: kind, origin, summary and its options (type, default, help)."""
    from doodlecam.registry import discover

    dirs = tuple(ctx.obj.get("plugin_dirs", ())) + tuple(plugin_dirs)
    infos = discover(dirs)
    matches = [i for i in infos if i.name == name and (kind is None or i.kind == kind)]
    if not matches:
        names = sorted({i.name for i in infos if i.kind != "?"})
        raise PluginError(f"no plugin named '{name}'; available: {', '.join(names)} (see 'doodlecam plugins')")
    for n, info in enumerate(matches):
        if n:
            click.echo("")
        if info.kind == "?":
            raise PluginError(f"drop-in {info.origin} failed to load: {info.error}")
        cls = info.load()  # a broken plugin raises a one-line PluginError naming it
        click.echo(f"{info.name}  ({info.kind})")
        click.echo(f"  summary      {cls.summary}")
        click.echo(f"  origin       {info.origin}")
        click.echo(f"  class        {cls.__module__}.{cls.__qualname__}")
        click.echo(f"  plugin API   {getattr(cls, 'api_version', '?')}")
        if info.kind == "postprocessor":
            click.echo(f"  writes       STEM{cls.extension or '(no extension)'}")
        if info.kind == "tracer" and getattr(cls, "extensions", ()):
            click.echo(f"  reads        {' '.join(cls.extensions)}")
        doc = _inspect.getdoc(cls)
        if doc and doc != _inspect.getdoc(cls.__mro__[1]):
            click.echo("")
            for line in doc.split("\n\n")[0].splitlines():
                click.echo(f"  {line}")
        opts = cls.options
        click.echo("")
        if not opts:
            click.echo("  options      none")
            continue
        click.echo("  options:")
        w = max(len(o.name) for o in opts)
        tw = max(len(o.type.__name__) for o in opts)
        for o in opts:
            extra = f" (one of: {', '.join(map(str, o.choices))})" if getattr(o, "choices", None) else ""
            click.echo(f"    {o.name:<{w}}  {o.type.__name__:<{tw}}  default {_fmt(o.default)}")
            click.echo(f"    {'':<{w}}  {o.help}{extra}")
        flag, table = SETTING.get(info.kind, (None, None))
        if flag:
            click.echo("")
            click.echo(f"  set with     {flag.format(name=info.name)}, or in a machine profile:")
            click.echo(f"               [{table}.{info.name}]")
            o = next((o for o in opts if o.default is not None), opts[0])  # unset defaults have no TOML
            click.echo(f"               {o.name} = {_toml(o.default)}")


def _toml(value) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return repr(value)
