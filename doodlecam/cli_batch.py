"""``doodlecam batch IN_DIR OUT_DIR``: convert a folder (see doodlecam.batch)."""

from __future__ import annotations

import os
from pathlib import Path

import click

from .cli import PLUGIN_DIR, _pairs


@click.command()
@click.argument("in_dir", type=click.Path(path_type=Path, file_okay=False))
@click.argument("out_dir", type=click.Path(path_type=Path, file_okay=False))
@click.option("-r", "--recursive", is_flag=True, help="Also convert the files in sub-folders (mirrored in OUT_DIR).")
@click.option("--include", multiple=True, metavar="GLOB", help="Only files matching (relative path, or name if no '/'; repeatable).")
@click.option("--exclude", multiple=True, metavar="GLOB", help="Skip files matching (repeatable).")
@click.option("-j", "--jobs", type=click.IntRange(min=1), default=None,
              help="Worker processes. Default: the number of cores.")
@click.option("--force", is_flag=True, help="Convert every file again, even if up to date.")
@click.option("--scheduler", metavar="ADDRESS",
              help="Run on a Dask distributed cluster (e.g. tcp://host:8786); IN_DIR and OUT_DIR must be shared "
                   "at the same paths. Needs: pip install 'doodlecam[dask]'.")
@click.option("--no-progress", is_flag=True, help="No progress bar (it is shown only on a terminal anyway).")
@click.option("--json", "as_json", is_flag=True, help="Print report.json's file list as JSON instead of the table.")
@click.option("-m", "--machine", default="doodlebot", show_default=True, help="Machine profile: a name or a .toml path.")
@click.option("--tracer", help="Tracer plugin (default: chosen by file type; 'edges' for pictures).")
@click.option("--tracer-opt", multiple=True, metavar="KEY=VALUE", help="Tracer option (repeatable).")
@click.option("--post", "posts", multiple=True, metavar="NAME",
              help="Post-processor (repeatable). Default: plc, gcode and svg.")
@click.option("--post-opt", multiple=True, metavar="POST.KEY=VALUE", help="Post option, e.g. gcode.pen_up='M5' (repeatable).")
@click.option("--solver", help="Planner: reach (default), lp[:backend], qp[:backend]. Default: the profile's.")
@click.option("--smoothing", type=float, help="Weight of the smoothing QP against time (solver qp).")
@click.option("--width", type=float, metavar="MM", help="Target drawing width in mm (aspect kept).")
@click.option("--height", type=float, metavar="MM", help="Target drawing height in mm (aspect kept).")
@click.option("--scale", type=float, metavar="MM", help="Fixed scale: mm per source unit.")
@click.option("--margin", type=float, metavar="MM", help="Margin inside the work area (default: the profile's).")
@click.option("--rotate", type=click.Choice(["0", "90", "180", "270", "auto"]), help="Quarter turns counter-clockwise.")
@click.option("--fit", type=click.Choice(["canvas", "ink"]), help="Fit the whole picture frame or only what is drawn.")
@click.option("--keep-direction", is_flag=True, default=None, help="Never draw a stroke backwards.")
@PLUGIN_DIR
def batch(in_dir, out_dir, recursive, include, exclude, jobs, force, scheduler, no_progress, as_json, machine, tracer,
          tracer_opt, posts, post_opt, solver, smoothing, width, height, scale, margin, rotate, fit, keep_direction,
          plugin_dirs):
    """Convert every picture in IN_DIR into OUT_DIR, in parallel.

    \b
    Outputs mirror the input tree: IN_DIR/sub/a.png -> OUT_DIR/sub/a.plc, .gcode, .svg.
    Up-to-date files are skipped (OUT_DIR/.doodlecam-manifest.json); an interrupted
    batch resumes on re-run. Writes OUT_DIR/report.json and OUT_DIR/index.html.
    Exit code 1 if any file failed.
    """
    from .batch import BatchFailed, BatchInterrupted, BatchOptions, run_batch, summary_table

    post_opts: dict[str, dict[str, str]] = {}
    for key, val in _pairs(post_opt, "--post-opt").items():
        name, dot, opt = key.partition(".")
        if not dot:
            raise click.BadParameter(f"'{key}' must be POST.KEY=VALUE, e.g. gcode.pen_up=M5", param_hint="--post-opt")
        post_opts.setdefault(name, {})[opt] = val
    options = BatchOptions(
        machine=machine, tracer=tracer, tracer_options=_pairs(tracer_opt, "--tracer-opt"),
        posts=tuple(posts) or ("plc", "gcode", "svg"), post_options=post_opts, solver=solver, smoothing=smoothing,
        plugin_dirs=tuple(os.fspath(Path(d).resolve()) for d in plugin_dirs),
        layout={k: v for k, v in dict(width=width, height=height, scale=scale, margin=margin, rotate=rotate, fit=fit).items()
                if v is not None},
        order={"reverse": False} if keep_direction else {},
    )
    unused = set(post_opts) - set(options.posts)
    if unused:
        raise click.BadParameter(f"options given for '{sorted(unused)[0]}', which is not among the posts {', '.join(options.posts)}",
                                 param_hint="--post-opt")
    result = run_batch(in_dir, out_dir, options, recursive=recursive, include=include, exclude=exclude, jobs=jobs,
                       force=force, scheduler=scheduler, progress=False if no_progress else None)
    if as_json:
        import json

        click.echo(json.dumps(result.files, indent=1, ensure_ascii=False))
    else:
        click.echo(summary_table(result))
        click.echo(f"report: {out_dir / 'report.json'}  preview: {out_dir / 'index.html'}")
    if result.interrupted:
        raise BatchInterrupted(f"interrupted; {result.count('converted')} files finished and are kept; "
                               "re-run the same command to resume")
    if result.failed:
        raise BatchFailed(f"{result.failed} of {len(result.files)} files failed (listed above and in "
                          f"{out_dir / 'report.json'}); fix them and re-run: converted files are skipped")
