"""``doodlecam inspect``: a PLC packet file's header and commands.
"""

from __future__ import annotations

from pathlib import Path

import click


@click.command()
@click.argument("file", type=click.Path(path_type=Path))
@click.option("--csv", "as_csv", is_flag=True, help="Print the commands as CSV.")
@click.option("--limit", default=20, show_default=True, help="Commands to show (0 = all).")
def inspect(file, as_csv, limit):
    """Print a PLC packet file (or an EiBotBoard .ebb job): header and commands."""
    from doodlecam.errors import InputError
    from doodlecam.link.plc.packetfile import read_plc, to_csv

    if file.suffix.lower() == ".ebb":  # an EiBotBoard command stream (doodlecam convert --post ebb)
        from doodlecam.cli.ebb import inspect_ebb

        return inspect_ebb(file, limit)
    try:
        data = file.read_bytes()
    except OSError as e:
        raise InputError(f"{file}: cannot read ({e.strerror}); check the path") from None
    header, commands = read_plc(data, name=str(file))
    if as_csv:
        click.echo(to_csv(header, commands), nl=False)
        return
    for key, val in vars(header).items():
        if key.startswith("draw_accel") and header.version < 2:
            continue  # a version 1 file does not say
        click.echo(f"{key:<16} {val}")
    pauses = sum(c.type == 2 for c in commands)
    if pauses:
        click.echo(f"{'pen changes':<16} {pauses} (PAUSE commands)")
    shown = commands if limit == 0 else commands[:limit]
    click.echo(f"{'command_no':>10} {'type':>5} {'x':>10} {'y':>10}")
    for c in shown:
        click.echo(f"{c.command_no:>10} {('DRAW', 'MOVE', 'PAUSE')[c.type]:>5} {c.x:>10} {c.y:>10}"
                   + (f"   pen change: fit pen {c.x}" if c.type == 2 else ""))
    if len(shown) < len(commands):
        click.echo(f"... {len(commands) - len(shown)} more (--limit 0 shows all)")
