"""``doodlecam machines``: list the profiles, make one for your machine (``new``), check it (``check``).
"""

from __future__ import annotations

import re
from pathlib import Path

import click

from doodlecam.cli import complete

from doodlecam.errors import DoodleError, MachineError

NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


@click.group(invoke_without_command=True)
@click.pass_context
def machines(ctx):
    """List the machine profiles, where each comes from (or: new, check).

    \b
    Search order (the first profile of a name wins): a .toml path given to
    --machine; $DOODLECAM_MACHINES; your profile folder (see 'machines new');
    ./machines; the profiles built into doodlecam.
    """
    if ctx.invoked_subcommand is not None:
        return
    from doodlecam.machine import find_machines, load_machine, user_machine_dir

    for name, entry in find_machines().items():
        try:
            desc = load_machine(entry.path).description
        except DoodleError as e:
            desc = f"INVALID: {e}"
        shadow = f"; hides {', '.join(str(p) for p in entry.shadows)}" if entry.shadows else ""
        click.echo(f"  {name:<12} {entry.origin:<10} {desc}  [{entry.path}{shadow}]")
    click.echo(f"your profiles go in {user_machine_dir()}  (doodlecam machines new NAME)")


@machines.command()
@click.argument("name")
@click.option("--from", "template", default="doodlebot", show_default=True, metavar="PROFILE", shell_complete=complete.machines,
              help="Start from this profile: doodlebot (PLC), grbl-servo, grbl-z, fivebar, or any name or .toml path.")
@click.option("--force", is_flag=True, help="Replace a profile of that name in your folder.")
def new(name, template, force):
    """Write a commented starter profile NAME into your profile folder.

    Edit the values it marks (work area, steps/mm, speeds, accelerations, pen
    commands), then run 'doodlecam machines check NAME'. README "Your machine"
    walks through measuring them; 'doodlecam calibrate' draws a test pattern.
    """
    from doodlecam.atomic import write_bytes
    from doodlecam.machine import load_machine, resolve_machine, user_machine_dir

    if not NAME_RE.match(name) or name.endswith(".toml"):
        raise MachineError(f"'{name}' is not a profile name; use letters, digits, '-', '_' and '.', "
                           "e.g. my-plotter")
    src = resolve_machine(template)
    text = src.read_text(encoding="utf-8")
    new_text, n = re.subn(r'(?m)^name\s*=\s*".*"', f'name = "{name}"', text, count=1)
    if n != 1:
        raise MachineError(f"{src}: has no [machine] name line to start from; pick another --from")
    header = (f"# Profile '{name}', started from '{template}' by 'doodlecam machines new'.\n"
              "# Measure your machine and change the values below (README, \"Your machine\"),\n"
              f"# then run: doodlecam machines check {name}\n#\n")
    dest = user_machine_dir() / f"{name}.toml"
    if dest.exists() and not force:
        raise MachineError(f"{dest} exists; edit it, or add --force to start it again from '{template}'")
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
        write_bytes(dest, (header + new_text).encode("utf-8"))
    except OSError as e:
        raise MachineError(f"{dest}: cannot write ({e.strerror or e}); check the folder's permissions") from None
    load_machine(dest)  # what we wrote loads
    click.echo(f"wrote {dest}")
    click.echo(f"next: edit it, then 'doodlecam machines check {name}'; convert with '--machine {name}'")


def _t(seconds: float) -> str:
    return f"{seconds:.2f} s" if seconds < 60 else f"{seconds / 60:.1f} min"


def explain(machine, origin: str = "") -> list[str]:
    """What a (valid) profile means, in words: one line each."""
    import numpy as np

    from doodlecam.plan.travel import axis_move_time, make_travel

    m = machine
    law = m.travel_law
    lines = [f"{m.name}: {m.description or '(no description)'}",
             f"  profile        {m.source}" + (f"  ({origin})" if origin else ""),
             f"  kinematics     {m.kinematics}",
             f"  work area      {m.width:g} x {m.height:g} mm; drawings fill {m.width - 2 * m.margin:g} x "
             f"{m.height - 2 * m.margin:g} mm inside a {m.margin:g} mm margin; home at ({m.home[0]:g}, {m.home[1]:g})"]
    for ax in m.axes:
        reach_t, reach_d = ax.max_velocity / ax.max_acceleration, ax.max_velocity ** 2 / (2 * ax.max_acceleration)
        lines.append(f"  {ax.name} axis         up to {ax.max_velocity:g} mm/s ({ax.max_velocity * 60:g} mm/min), "
                     f"{ax.max_acceleration:g} mm/s^2: full speed after {reach_t * 1000:.0f} ms and {reach_d:.1f} mm; "
                     f"{ax.steps_per_mm:g} steps/mm ({1000 / ax.steps_per_mm:.1f} um a step, "
                     f"{ax.max_velocity * ax.steps_per_mm / 1000:.1f} kHz at full speed)")
    pen = m.pen
    for k, p in enumerate(m.pens or (pen,), 1):
        caps = [f"at most {p.max_speed:g} mm/s"] if p.max_speed else []
        caps += [f"{p.max_accel:g} mm/s^2 per axis"] if p.max_accel else []
        lines.append(f"  {p.describe(k) if m.pens else 'pen':<14} {p.width:g} mm wide; lifts in {p.up_delay:g} s, lowers "
                     f"in {p.down_delay:g} s; " + (f"draws {' and '.join(caps)}" if caps else "draws as fast as the axes allow")
                     + (f"; draws layers {', '.join(p.layers)}" if p.layers else ""))
    corner = make_travel(np.zeros(2), np.array([m.width, m.height]), m).duration
    lines.append(f"  pen up         corner to corner ({np.hypot(m.width, m.height):.0f} mm) in {_t(corner)} "
                 f"({law} travel law, {m.move_speed[0]:g} mm/s per axis)")
    if m.kinematics == "cartesian":
        v = min(m.x.max_velocity, pen.max_speed or np.inf)
        across = float(axis_move_time(m.width - 2 * m.margin, v, m.x.max_acceleration))
        lines.append(f"  pen down       a straight line across the page ({m.width - 2 * m.margin:g} mm) in {_t(across)}; "
                     "curves take longer: the planner slows the pen where they turn")
    lines.append(f"  samples        a velocity sample every {m.delta_time * 1000:g} ms (PLC); fit within "
                 f"{m.tolerance:g} mm by degree-{m.degree} B-splines; pen kept within {m.path_tolerance:g} mm between samples")
    for section, opts in sorted(m.plugin_options.items()):
        lines.append(f"  [{section}]" + " " * max(1, 13 - len(section)) + ", ".join(f"{k} = {v!r}" for k, v in opts.items()))
    if m.kinematics == "cartesian":
        from doodlecam.link.grbl.timing import grbl_settings_for

        dollar = grbl_settings_for(m)  # the settings the G-code post's header assumes

        def group(keys, unit):
            return " ".join(f"{k}={dollar[k]:g}" for k in keys) + f" ({unit})"

        lines.append("  GRBL settings  " + "  ".join([
            group(("$100", "$101"), "steps/mm"), group(("$110", "$111"), "mm/min"), group(("$120", "$121"), "mm/s^2"),
            group(("$130", "$131"), "mm, max travel"), group(("$11", "$1"), "junction deviation mm, step idle ms")]))
    elif m.kinematics == "axidraw":
        lines.append("  board          an EiBotBoard: 'doodlecam convert --post ebb', then 'doodlecam send JOB.ebb --serial "
                     "auto' (docs/ebb.md)")
    else:
        lines.append(f"  GRBL settings  none: GRBL drives cartesian machines; '{m.kinematics}' runs from the PLC samples")
    return lines


@machines.command()
@click.argument("name", shell_complete=complete.machines)
@click.option("--plugin-dir", "plugin_dirs", multiple=True, type=click.Path(file_okay=False),
              help="Folder of drop-in plugin .py files (for the profile's plugin sections).")
def check(name, plugin_dirs):
    """Validate profile NAME (or a .toml path) and say what it means: work area, speeds,
    accelerations, the time to cross the page, and the GRBL $ settings it needs."""
    from doodlecam.checks import check_profile_plugins
    from doodlecam.machine import find_machines, load_machine
    from doodlecam.registry import kinematics_for

    machine = load_machine(name)
    check_profile_plugins(machine, plugin_dirs)
    kinematics_for(machine, plugin_dirs)  # the kinematics plugin accepts its [kinematics] table
    entry = find_machines().get(name)
    origin = entry.origin if entry is not None and Path(entry.path) == Path(machine.source) else "path"
    for line in explain(machine, origin):
        click.echo(line)
    for w in machine.warnings:  # plausible enough to run, but worth a look (doodlecam.plausible)
        click.echo(f"  warning: {w}")
    click.echo("OK: the profile is valid" + (f", with {len(machine.warnings)} warning"
                                             f"{'s' if len(machine.warnings) > 1 else ''} above" if machine.warnings else ""))
