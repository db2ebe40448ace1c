"""``doodlecam machines``: the machine profiles on the search path.
"""

from __future__ import annotations

import click

from doodlecam.errors import DoodleError


@click.command()
def machines():
    """List the machine profiles found on the search path."""
    from doodlecam.machine import available_machines, load_machine

    for name, path in available_machines().items():
        try:
            desc = load_machine(path).description
        except DoodleError as e:
            desc = f"INVALID: {e}"
        click.echo(f"  {name:<12} {desc}  [{path}]")
