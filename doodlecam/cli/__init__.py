"""The ``doodlecam`` command line.

Only click is imported at start-up; every command imports the stages it needs,
so ``doodlecam --help`` answers fast. Errors a user can cause print one line
and exit non-zero, without a traceback.
"""

from __future__ import annotations

import sys

import click

from doodlecam import __version__
from doodlecam.errors import DoodleError, interrupted

# Commands that live in their own modules, imported only when invoked (or
# when --help lists them): "name": "module:function".
LAZY_COMMANDS: dict[str, str] = {
    "convert": "doodlecam.cli.convert:convert",
    "machines": "doodlecam.cli.machines:machines",
    "calibrate": "doodlecam.cli.calibrate:calibrate",
    "inspect": "doodlecam.cli.inspect:inspect",
    "send": "doodlecam.cli.send:send",
    "sim": "doodlecam.cli.send:sim",
    "machine": "doodlecam.cli.machine:machine",
    "plot": "doodlecam.cli.plot:plot",
    "motion": "doodlecam.cli.motion:motion",
    "learn": "doodlecam.cli.motion:learn",
    "batch": "doodlecam.cli.batch:batch",
    "plugins": "doodlecam.cli.plugins:plugins",
    "studio": "doodlecam.cli.studio:studio",
}


class LazyGroup(click.Group):
    """A click group that imports a command's module only when it is needed."""

    def list_commands(self, ctx):
        return sorted(set(super().list_commands(ctx)) | set(LAZY_COMMANDS))

    def get_command(self, ctx, name):
        if name in LAZY_COMMANDS and name not in self.commands:
            import importlib

            module, attr = LAZY_COMMANDS[name].split(":")
            return getattr(importlib.import_module(module), attr)
        return super().get_command(ctx, name)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="doodlecam")
@click.option("-v", "--verbose", count=True, help="Say more: each stage's time (convert). Before the command: doodlecam -v convert ...")
@click.pass_context
def cli(ctx, verbose):
    """Turn pictures into time-optimal pen-plotter jobs.

    \b
    trace -> fit B-splines -> order -> plan (time-optimal) -> sample -> post
    Start with:  doodlecam convert PICTURE -o out/    (a photo or sketch: PNG, JPEG; or an SVG, DXF)
    No picture at hand:  doodlecam calibrate -o out/   (a test pattern for the default machine)
    """
    ctx.meta["doodlecam.verbose"] = verbose  # shared with every sub-command's context (cli.progress)




def main(argv=None) -> int:
    try:
        return _run(argv)
    except SystemExit:
        raise
    except BaseException as e:  # Ctrl-C, wherever it lands (a compiled kernel turns it into a SystemError)
        if not interrupted(e):
            raise
        return _interrupted()


def _interrupted() -> int:
    from doodlecam import atomic

    click.echo("doodlecam: interrupted" + ("" if atomic.renamed else "; no file was written"), err=True)
    return 130


COMPLETE_VAR = "_DOODLECAM_COMPLETE"  # the shell's completion script sets it (README: shell completion)


def _run(argv) -> int:
    args = sys.argv[1:] if argv is None else list(argv)
    import os

    if os.environ.get(COMPLETE_VAR):  # what click's main would do; this main does not call it (below)
        from click.shell_completion import shell_complete

        return shell_complete(cli, {}, "doodlecam", COMPLETE_VAR, os.environ[COMPLETE_VAR])
    try:
        # make_context + invoke rather than cli.main: click's main turns Ctrl-C into Abort after
        # printing a blank line, and the interrupt is one line here
        with cli.make_context("doodlecam", args) as ctx:
            rv = cli.invoke(ctx)
        if isinstance(rv, int):
            return rv
    except click.exceptions.Exit as e:
        return e.exit_code
    except click.ClickException as e:
        e.show()
        return e.exit_code
    except click.exceptions.Abort as e:
        if interrupted(e):
            return _interrupted()
        click.echo("doodlecam: aborted", err=True)
        return 130
    except DoodleError as e:
        if interrupted(e):  # a wrapped Ctrl-C
            return _interrupted()
        click.echo(f"doodlecam: error: {e}", err=True)
        return e.exit_code
    except BrokenPipeError:  # `doodlecam convert ... | head`: the reader left; say nothing more
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # Python flushes stdout at exit
        return 1
    return 0


def entry() -> None:
    """The console-script entry point of installs made before it moved to doodlecam.__main__."""
    sys.exit(main())
