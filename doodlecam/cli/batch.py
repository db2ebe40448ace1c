"""``doodlecam batch IN_DIR OUT_DIR``: convert a folder (see doodlecam.batch.runner)."""

from __future__ import annotations

import os
from pathlib import Path

import click

from doodlecam.cli.options import job_kwargs, job_options


@click.command()
@click.argument("in_dir", type=click.Path(path_type=Path, file_okay=False))
@click.argument("out_dir", type=click.Path(path_type=Path, file_okay=False))
@click.option("-r", "--recursive", is_flag=True, help="Also convert the files in sub-folders (mirrored in OUT_DIR).")
@click.option("--include", multiple=True, metavar="GLOB", help="Only files matching (relative path, or name if no '/'; repeatable).")
@click.option("--exclude", multiple=True, metavar="GLOB", help="Skip files matching (repeatable).")
@click.option("-j", "--jobs", type=click.IntRange(min=1), default=None,
              help="Worker processes. Default: the number of cores.")
@click.option("--force", is_flag=True, help="Convert every file again, even if up to date.")
@click.option("--recycle-after", type=click.IntRange(min=0), default=None, metavar="FILES",
              help="Replace each worker process by a fresh one after about this many files, so memory cannot "
                   "grow over a long batch (0 = never). Default: 250.")
@click.option("--scheduler", metavar="ADDRESS",
              help="Run on a Dask distributed cluster (e.g. tcp://host:8786); IN_DIR and OUT_DIR must be shared "
                   "at the same paths. Needs: pip install 'doodlecam[dask]'.")
@click.option("--no-progress", is_flag=True, help="No progress bar (it is shown only on a terminal anyway).")
@click.option("--json", "as_json", is_flag=True, help="Print report.json's file list as JSON instead of the table.")
@job_options
def batch(in_dir, out_dir, recursive, include, exclude, jobs, force, recycle_after, scheduler, no_progress, as_json,
          **job):
    """Convert every picture in IN_DIR into OUT_DIR, in parallel.

    \b
    Outputs mirror the input tree: IN_DIR/sub/a.png -> OUT_DIR/sub/a.plc, .gcode, .svg.
    Up-to-date files are skipped (OUT_DIR/.doodlecam-manifest.json); an interrupted
    batch resumes on re-run. Writes OUT_DIR/report.json and OUT_DIR/index.html.
    One batch at a time per OUT_DIR (a lock). Worker processes are replaced every
    --recycle-after files so memory stays flat; report.json has each one's memory.
    Exit code: 0 all converted; 1 some files failed (listed); 2 an error that is not
    one file's (nothing to convert, a bad option, OUT_DIR busy with another batch,
    the manifest or report cannot be written); 130 interrupted (re-run to resume).
    """
    from doodlecam.batch.options import BatchOptions
    from doodlecam.batch.report import summary_table
    from doodlecam.cli.firstrun import first_run_notice
    from doodlecam.batch.runner import (
        RECYCLE_AFTER,
        BatchFailed,
        BatchInterrupted,
        run_batch,
    )

    kw = job_kwargs(**job)
    kw["plugin_dirs"] = tuple(os.fspath(Path(d).resolve()) for d in kw["plugin_dirs"])  # workers may run elsewhere
    options = BatchOptions(**kw)
    result = run_batch(in_dir, out_dir, options, recursive=recursive, include=include, exclude=exclude, jobs=jobs,
                       force=force, scheduler=scheduler, progress=False if no_progress else None,
                       recycle_after=RECYCLE_AFTER if recycle_after is None else recycle_after,
                       before_work=first_run_notice)
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
