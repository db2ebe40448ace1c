"""The stages wired together: file -> Drawing -> Job -> output files.

Each function takes the previous stage's value and returns the next; the CLI
and the batch runner call ``convert``. Outputs are written only after every
stage and every post succeeded, each to a temporary file renamed into place,
so a failure never leaves a half-written job behind.
"""

from __future__ import annotations

import contextlib
import gc
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from doodlecam import checks, registry
from doodlecam.atomic import replace_all
from doodlecam.collector import enable_promoted
from doodlecam.errors import (
    DoodleError,
    InputError,
    OutputError,
    PlanError,
    PluginError,
    interrupted,
)
from doodlecam.machine import Machine
from doodlecam.memory import memory_mb
from doodlecam.model import Drawing, Job, Stroke, prime_splines
from doodlecam.options import ConvertOptions
from doodlecam.trace.raster import IMAGE_EXTENSIONS

FIT_BATCH = 500  # strokes fitted per compiled call: a progress report and a chance for Ctrl-C between


@dataclass(frozen=True, kw_only=True)
class Settings(ConvertOptions):
    """The options of one conversion with the machine profile loaded."""

    machine: Machine
    workers: int = 1  # processes planning the strokes (the job is the same with any number)

    def __post_init__(self):
        super().__post_init__()
        for key, value in registry.canonical_fields(self).items():  # --post GCODE is the gcode post
            object.__setattr__(self, key, value)


def _guarded(what: str, fn, *args):
    """Call plugin code: its own DoodleErrors pass, anything else names the plugin."""
    try:
        return fn(*args)
    except DoodleError:
        raise
    except Exception as e:
        if interrupted(e):  # Ctrl-C inside a compiled kernel: not the plugin's failure
            raise KeyboardInterrupt from None
        raise PluginError(f"{what} failed: {type(e).__name__}: {e}") from e


def pick_tracer(path: Path, settings: Settings) -> type:
    """The tracer named in settings, else the first one that reads this file type."""
    return checks.pick_tracer(path, settings.tracer, settings.plugin_dirs)


def trace(path: Path, settings: Settings) -> Drawing:
    checks.check_input(path)
    cls = pick_tracer(path, settings)
    opts = cls.resolve_options(settings.machine.plugin_options.get(f"trace.{cls.name}", {}), settings.tracer_options)
    tracer = cls()
    tracer.profile_options = settings.machine.plugin_options  # 'auto' applies the chosen tracer's [trace.NAME]
    if path.suffix.lower() in IMAGE_EXTENSIONS:  # tell the tracer how large a pixel will be drawn
        from doodlecam.trace.layout import picture_scale
        from doodlecam.trace.raster import picture_size

        size = picture_size(path)
        if size is not None:
            tracer.mm_per_px = picture_scale(*size, settings.machine, settings.layout, str(path))
            tracer.pen_mm = settings.machine.pen.width
    drawing = _guarded(f"tracer '{cls.name}' on {path}", tracer.trace, path, opts)
    if not isinstance(drawing, Drawing):
        raise PluginError(f"tracer '{cls.name}' returned {type(drawing).__name__}, not a Drawing; fix the plugin")
    if "tracer_reason" not in drawing.meta:  # say which tracer ran and why (auto says it itself)
        why = "chosen with --tracer" if settings.tracer else f"the default for {path.suffix.lower() or 'such'} files"
        drawing = replace(drawing, meta={"tracer": cls.name, **drawing.meta, "tracer_reason": why})
    return drawing


Progress = Callable[[str, int, int], None]  # (stage, done, total): where a conversion is, for a status line


def _quiet(stage: str, done: int = 0, total: int = 0) -> None:
    """No progress report."""


def plan_job(drawing: Drawing, machine: Machine, solver: str = "reach", plugin_dirs=(), order: dict | None = None,
             smoothing: float | None = None, fitted: list[Stroke] | None = None, workers: int = 1,
             progress: Progress = _quiet, pens: dict[str, tuple[int, str]] | None = None) -> Job:
    """Order, fit, plan and sample a drawing already in machine millimetres.

    ``progress(stage, done, total)`` is told each stage ("ordering", "fitting", "planning":
    planning, sampling and their checks, stroke by stroke) and, within the last two, how many
    of the strokes are done.

    ``order`` overrides the profile's [order] options (doodlecam.options.ORDER_DEFAULTS).
    ``fitted``: strokes already ordered and fitted (an edited job, e.g. from the
    studio): planned as given, without ordering or fitting ``drawing`` again.
    ``pens``: with ``fitted``, the pen (number, why) each layer was given in the whole job, so that a few
    edited strokes are planned with their own pen's limits (assigned afresh to these strokes' layers
    alone, a layer could take another pen).
    ``workers``: processes that plan the strokes (doodlecam.plan.stroke; the job is the
    same with any number).
    """
    from doodlecam.geometry.corners import split_traced
    from doodlecam.geometry.fit import fit_many
    from doodlecam.geometry.order import order_strokes
    from doodlecam.plan.follow import JerkBound, jerk_limit
    from doodlecam.plan.planner import check_solver
    from doodlecam.plan.sample import whole_step_limits
    from doodlecam.plan.stroke import Context, plan_strokes
    from doodlecam.plan.travel import machine_law, make_travels, travel_time_by_law
    from doodlecam.options import order_options

    check_solver(solver)  # before the fitting, not after it
    colours = drawing.meta.get("layer_colours")
    smoothing = machine.smoothing if smoothing is None else smoothing
    kin = registry.kinematics_for(machine, plugin_dirs)
    kin.check_reachable(np.concatenate(drawing.polylines))
    timings: dict[str, float] = {}

    t0 = time.perf_counter()
    progress("ordering", 0, len(drawing.polylines))
    if fitted is None:
        oo = order_options({**machine.order, **(order or {})})
        # One layer after another, strokes ordered within each; layers grouped by pen (each pen
        # fitted once) unless [order] layers = "file" keeps the drawing's order.
        names = drawing.layers or ("",) * len(drawing.polylines)
        pens = machine.assign_pens(names, colours)  # in the drawing's order, so the choice never depends on ours
        plotted = sorted(pens, key=lambda n: pens[n][0]) if oo["layers"] == "pen" else list(pens)  # stable
        ordered = []  # (source index, polyline, layer)
        here = np.asarray(machine.home, float)
        for layer in plotted:
            mine = [i for i, n in enumerate(names) if n == layer]
            # each layer starts where the previous one ended (the pen is changed there)
            o = order_strokes([drawing.polylines[i] for i in mine], here, allow_reverse=oo["reverse"],
                              merge=oo["merge"], budget=oo["budget"], moves=oo["moves"])
            ordered += [(mine[k], p, layer) for k, p in zip(o.source, o.polylines)]
            if o.polylines:
                here = np.asarray(o.polylines[-1][-1], float)
    timings["order"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    strokes = [] if fitted is None else [Stroke(spline=s.spline, source_index=s.source_index, fit_error=s.fit_error,
                                                layer=s.layer) for s in fitted]
    if fitted is not None and pens is None:  # an edited job keeps its order of layers
        pens = machine.assign_pens([*drawing.layers, *(s.layer for s in strokes)], colours)
    # A tracer may ask for its strokes to be cut where they turn sharper than an angle (the
    # vector tracer's corners, joined hatching's zig-zags): each piece is fitted on its own, so
    # the corner is exactly where the drawing puts it and the pen stops there, pen down.
    corner = float(drawing.meta.get("split_corners_deg", 0.0))
    # A line traced from pixels turns at every step of its staircase: its corners are found over
    # a support of a few pixels of the grid traced, at least a few pen widths (geometry.corners).
    traced, support, smooth, arms = traced_corner_rule(drawing, machine)
    # FIT_BATCH strokes at a time in one compiled call (a generated drawing has thousands of
    # short paths), progress told between batches
    todo = ordered if fitted is None else []
    for k in range(0, len(todo), FIT_BATCH):
        progress("fitting", k, len(todo))
        batch = [(i, piece, layer) for i, p, layer in todo[k:k + FIT_BATCH]
                 for piece in (split_traced(p, support, traced, smooth, arms) if traced > 0 else (p,))]
        fits = fit_many([piece for _, piece, _ in batch], machine.degree, machine.tolerance, corner=corner)
        for (i, _, layer), pieces in zip(batch, fits):
            strokes += [Stroke(spline=spline, source_index=i, fit_error=err, layer=layer) for spline, err in pieces]
    timings["fit"] = time.perf_counter() - t0
    ordered = None  # the fitted strokes replace the ordered polylines (memory at 10^5 paths)

    # Between sample instants the PLC's ramps stray from the curve where its turning
    # changes fast (docs/sampling.md): with a path tolerance the planner bounds the
    # pen's jerk across the path and the sampler pulls the pen onto the curve there too.
    path_tol = machine.path_tolerance
    jerk = JerkBound(jerk_limit(path_tol, machine.delta_time)) if path_tol > 0 else None
    steps = (machine.x.steps_per_mm, machine.y.steps_per_mm)
    # Each layer is drawn with its pen, which may cap speed and acceleration below the machine's.
    pen_of = {name: k for name, (k, _) in pens.items()}
    by_pen = {k: pen_limits(machine, machine.pen_number(k), kin) for k in sorted(set(pen_of.values()))}
    # planned within what whole-step rounding leaves, so the samples (which keep
    # that, sample.whole_step_limits) need no extra periods to follow the plan
    by_pen = {k: (lim, whole_step_limits(lim, steps, machine.delta_time)) for k, lim in by_pen.items()}
    ctx = Context(delta_time=machine.delta_time, solver=solver, smoothing=smoothing, path_tolerance=path_tol,
                  jerk=jerk, steps=steps, kinematics=kin, pens=by_pen)
    t0 = time.perf_counter()
    finished = [0]

    def planned_some(k: int) -> None:
        finished[0] += k
        progress("planning", finished[0], len(strokes))

    progress("planning", 0, len(strokes))
    outcomes = plan_strokes(ctx, strokes, [pen_of[s.layer] for s in strokes], workers, planned_some)
    timings["plan"] = time.perf_counter() - t0  # plan, sample and re-plan: one pass per stroke
    planned = [o.stroke for o in outcomes]
    samples = tuple(o.samples for o in outcomes)
    worst_acc = max((o.ratios[0] for o in outcomes), default=0.0)
    worst_vel = max((o.ratios[1] for o in outcomes), default=0.0)
    between = max((o.worst_deviation for o in outcomes), default=0.0)
    nonlinear = kin.linear_map is None

    points = [np.asarray(machine.home, float)]
    for s in planned:
        points += [s.spline.start, s.spline.end]
    points.append(np.asarray(machine.home, float))
    travels = make_travels(points, machine)
    meta = {
        "travel_law": machine_law(machine),
        "travel_time_by_law": travel_time_by_law(travels, machine),
        "solver": solver,
        "worst_acceleration_ratio": worst_acc,
        "worst_velocity_ratio": worst_vel,
        "max_fit_error_mm": max((s.fit_error for s in planned), default=0.0),
        "max_between_samples_mm": between,
        "path_tolerance_mm": path_tol,
        "strokes_replanned": sum(1 for o in outcomes if o.replans),
        "strokes_slowed_for_ramps": sum(1 for o in outcomes if o.slowed_for_ramps),
        "strokes_slowed_for_path": sum(1 for o in outcomes if o.slowed < 1.0),
        "worst_ramp_ratio": max((o.ramp for o in outcomes), default=0.0) if nonlinear else None,
        "control_points": sum(len(s.spline.control) for s in planned),
        "corners_kept": corners_kept(planned),
        "layer_colours": dict(colours or {}),
        "layer_pens": {s.layer: pen_of[s.layer] for s in planned},  # in plotting order
        "pen_reasons": {n: pens[n][1] for n in dict.fromkeys(s.layer for s in planned)},
        # grouped by pen only where pens are shared ([[pen]]); else each layer has a pen of its own, in file order
        "layer_order": oo["layers"] if fitted is None and machine.pens else "file",
        "timings": timings,
    }
    return Job(machine=machine, strokes=tuple(planned), travels=travels, samples=samples,
               source=drawing.source, meta=meta)


TRACED_SUPPORT = 3.0  # scales (below) on either side of a traced corner


def traced_corner_rule(drawing: Drawing, machine: Machine) -> tuple[float, float, float, float]:
    """(angle in degrees, 0 = off; support, smoothing and arms in mm) of the corners kept on a
    traced picture's lines: the tracer's ``traced_corners_deg``, found over TRACED_SUPPORT x the
    largest of the scales that round or blur a corner on the grid traced: the pen width, the
    grid's pixel as drawn (``scale_mm_per_unit`` x ``grid_px``, picture px per traced px) and the
    tracer's own blur (``corner_blur_px``, traced px: Canny's sigma, contours' blur), the same at
    any resolution of the picture. The line is smoothed by the pixel (pen width or grid) before its
    turns are measured; the arms are fitted beyond TRACED_SUPPORT picture pixels too, where a
    picture coarser than the grid rounds its corners over its own pixels."""
    meta = drawing.meta
    angle = float(meta.get("traced_corners_deg", 0.0))
    px = float(meta.get("scale_mm_per_unit", 0.0))
    grid = px * float(meta.get("grid_px", 1.0))
    pixel = max(machine.pen.width, grid)
    support = TRACED_SUPPORT * max(pixel, grid * float(meta.get("corner_blur_px", 0.0)))
    return angle, support, pixel, max(support, TRACED_SUPPORT * px)


def corners_kept(strokes) -> int:
    """Corners kept exact: joins where one piece of a traced line ends and the next goes on from
    that very point, the pen stopping there without lifting (fit_pieces' cuts)."""
    n = 0
    for a, b in zip(strokes, strokes[1:]):
        if a.source_index == b.source_index >= 0 and a.layer == b.layer:
            (x0, y0), (x1, y1) = a.spline.end.tolist(), b.spline.start.tolist()
            n += x0 == x1 and y0 == y1  # np.array_equal of the two points, on Python floats (a third of its time)
    return n


def pen_limits(machine: Machine, pen, kin):
    """The planner's limits for drawing with ``pen``: its speed cap, and its acceleration cap
    on each paper axis (for machines whose axes are the paper's x and y)."""
    from doodlecam.plan.planner import Limits

    lim = Limits.from_machine(replace(machine, pen=pen), kin)
    if pen.max_accel is not None:
        checks.check_pens(machine, kin)
        lim = replace(lim, amax=np.minimum(lim.amax, pen.max_accel * np.abs(np.diag(lim.M))))
    return lim


def run_posts(job: Job, settings: Settings) -> list[tuple[str, str, bytes]]:
    """[(post name, file extension, bytes)] for every requested post."""
    out = []
    for name in settings.posts:
        cls = registry.get("postprocessor", name, settings.plugin_dirs)
        opts = cls.resolve_options(job.machine.plugin_options.get(f"post.{name}", {}), settings.post_options.get(name, {}))
        data = _guarded(f"post-processor '{name}'", cls().write, job, opts)
        if not isinstance(data, (bytes, bytearray)):
            raise PluginError(f"post-processor '{name}' returned {type(data).__name__}, not bytes; fix the plugin")
        out.append((name, cls.extension, bytes(data)))
    return out


def write_outputs(outdir: Path, stem: str, outputs: list[tuple[str, str, bytes]]) -> list[Path]:
    """Write all outputs atomically: temp files first, renamed only when all are written."""
    try:
        outdir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"{outdir}: cannot create output folder ({e.strerror}); choose another -o") from None
    names = [outdir / f"{stem}{ext}" for _, ext, _ in outputs]
    dupes = {n for n in names if names.count(n) > 1}
    if dupes:
        raise OutputError(f"two posts write {sorted(dupes)[0]}; request each post once")
    try:
        return replace_all((final, data) for (_, _, data), final in zip(outputs, names))
    except OSError as e:
        raise OutputError(f"{outdir}: cannot write output ({e.strerror}); check space and permissions") from None


LONG_JOB_S = 3600.0  # jobs longer than this get a warning with the estimate


def over_bounds(job: Job) -> list[str]:
    """Each measured figure of a planned job that is over its bound, in words (empty when all keep them)."""
    m, meta = job.machine, job.meta
    out = []
    fit = meta.get("max_fit_error_mm", 0.0)
    if fit > m.tolerance * (1 + 1e-6) + 1e-9:
        out.append(f"the fitted curves are up to {fit:.3f} mm off the traced lines, over the fit tolerance of {m.tolerance:g} mm")
    tol, between = meta.get("path_tolerance_mm", 0.0), meta.get("max_between_samples_mm", 0.0)
    if tol > 0 and between > tol * (1 + 1e-6) + 1e-9:
        out.append(f"the pen strays up to {between:.3f} mm off the curve between velocity samples, "
                   f"over the path tolerance of {tol:g} mm")
    for key, what in (("worst_acceleration_ratio", "acceleration"), ("worst_velocity_ratio", "velocity")):
        r = meta.get(key, 0.0)
        if r > 1.0 + 1e-6:
            out.append(f"the planned {what} reaches {r:.4f} times its limit")
    ramp = meta.get("worst_ramp_ratio")
    if ramp is not None and ramp > 1.0 + 1e-6:
        out.append(f"the actuators reach {ramp:.4f} times their limits along the sampled ramps")
    return out


def warnings_for(job: Job, drawing_meta: dict[str, Any]) -> list[str]:
    """What the user should know about a finished job, one sentence each."""
    out = list(drawing_meta.get("warnings", ()))  # the tracer's: what it could not draw
    spare = [c for c in pen_choice(job) if c["why"].startswith("no pen of its own")]
    if spare:
        named = (c["layer"] + (f" ({c['colour']})" if c["colour"] else "") + f" drawn with {c['pen']}" for c in spare)
        out.append("no pen of their own (by a pen's layers list, name or colour): " + ", ".join(named)
                   + "; give each a [[pen]] of its colour, or list it in a pen's layers")
    out += job.machine.warnings  # the profile's implausible values (doodlecam.plausible)
    if job.duration > LONG_JOB_S:
        out.append(f"the job takes {job.duration / 3600:.1f} hours ({job.duration / 60:.0f} min); check the tracer "
                   "options (a noisy picture traces to many strokes) or draw it smaller")
    short = drawing_meta.get("dropped_short", 0)
    if short:
        total = drawing_meta.get("strokes_traced")
        out.append(f"{short}{f' of {total}' if total else ''} traced stroke{'s' if short != 1 else ''} dropped: "
                   f"shorter than {drawing_meta.get('min_length_mm', job.machine.pen.width):g} mm "
                   "(the pen width, or [layout] min_length) at this size; draw it larger to keep them")
    return out + [f"{w}; allowed by --allow-deviation" for w in job.meta.get("allowed_deviations", ())]


@dataclass
class Result:
    job: Job
    outputs: list[Path]
    timings: dict[str, float]
    drawing_meta: dict[str, Any] = field(default_factory=dict)  # the laid-out drawing's meta (tracer, scale, drops)

    def grbl_estimate(self) -> float | None:
        """GRBL's time for the G-code written (the header's planner-model figure), None without G-code."""
        from doodlecam.link.grbl.timing import header_estimate

        for p in self.outputs:
            if Path(p).suffix.lower() in (".gcode", ".nc", ".ngc", ".gc"):
                try:
                    with open(p, encoding="ascii", errors="replace") as f:
                        return header_estimate(f.read(4000))
                except OSError:
                    return None
        return None

    def summary(self) -> dict[str, Any]:
        j = self.job
        d = self.drawing_meta
        scale = d.get("scale_mm_per_unit")
        width_px = d.get("line_width_px")
        return {
            "source": j.source,
            "machine": j.machine.name,
            "tracer": d.get("tracer"),
            "tracer_reason": d.get("tracer_reason"),
            "tracer_made": d.get("made"),  # the tracer's own line on what it drew (dots, a tour, flow lines)
            "line_width_mm": round(width_px * scale, 4) if width_px and scale else None,
            "scale_mm_per_px": scale if d.get("units_in") == "px" else None,
            "dropped_strokes": {"shorter_than_pen": d.get("dropped_short", 0)},
            "warnings": warnings_for(j, d),
            "strokes": len(j.strokes),
            "pen_lifts": j.pen_lifts,
            "pen_down_mm": round(j.pen_down_length, 3),
            "travel_mm": round(j.travel_length, 3),
            "job_time_s": round(j.duration, 3),
            "draw_time_s": round(j.draw_time, 3),
            "optimal_draw_time_s": round(sum(s.duration for s in j.strokes), 3),
            "samples": sum(len(s.velocity) for s in j.samples),
            "control_points": j.meta["control_points"],
            "corners_kept": j.meta.get("corners_kept", 0),
            "max_fit_error_mm": round(j.meta["max_fit_error_mm"], 4),
            "max_between_samples_mm": round(j.meta.get("max_between_samples_mm", 0.0), 4),
            "path_tolerance_mm": j.meta.get("path_tolerance_mm", 0.0),
            "strokes_replanned": j.meta.get("strokes_replanned", 0),
            "strokes_slowed_for_ramps": j.meta.get("strokes_slowed_for_ramps", 0),
            "strokes_slowed_for_path": j.meta.get("strokes_slowed_for_path", 0),
            "worst_ramp_ratio": (None if j.meta.get("worst_ramp_ratio") is None
                                 else round(j.meta["worst_ramp_ratio"], 6)),
            "worst_acceleration_ratio": round(j.meta["worst_acceleration_ratio"], 9),
            "worst_velocity_ratio": round(j.meta["worst_velocity_ratio"], 9),
            "travel_law": j.meta.get("travel_law", ""),
            "travel_time_by_law_s": {k: round(v, 3) for k, v in j.meta.get("travel_time_by_law", {}).items()},
            "outputs": [str(p) for p in self.outputs],
            "grbl_estimate_s": self.grbl_estimate(),
            "timings_s": {k: round(v, 3) for k, v in self.timings.items()},
            "peak_memory_mb": memory_mb()[1],  # the process's peak so far (in the studio: the server's)
            "layers": [n for n in j.layers if n] or [],
            "pen_changes": len(j.pen_changes),
            "layer_order": j.meta.get("layer_order", "file"),
            # the pen the job first pauses for the operator to fit (a profile with several pens), else None
            "first_pen_prompt": (j.machine.pen_number(j.pen_numbers[0]).describe(j.pen_numbers[0])
                                 if 0 in j.pen_pauses else None),
            "pens": {n: j.machine.pen_number(k).describe(k) for n, k in j.layer_pens.items() if n},
            "pen_choice": pen_choice(j),
        }


def pen_choice(job: Job) -> list[dict[str, Any]]:
    """Which layers (and their colours) each pen draws and why, in plotting order: one entry per
    layer, {"layer", "colour", "pen", "why"}."""
    colours, why = job.meta.get("layer_colours") or {}, job.meta.get("pen_reasons") or {}
    return [{"layer": n, "colour": colours.get(n, ""), "pen": job.machine.pen_number(k).describe(k),
             "why": why.get(n, "")} for n, k in job.layer_pens.items() if n]


def convert(path: str | Path, outdir: str | Path, settings: Settings, progress: Progress = _quiet) -> Result:
    """Trace, plan and post one file into ``outdir``; ``progress`` as for :func:`plan_job`, plus
    "tracing" first and "writing" last."""
    with rare_collections():
        return _convert(path, outdir, settings, progress)


GC_THRESHOLDS = (100_000, 50, 100)  # during a conversion (Python's own: 700, 10, 10)


@contextlib.contextmanager
def rare_collections():
    """Python's cyclic garbage collector run less often, the previous thresholds restored after: a job
    of 10^5 strokes holds millions of small objects that every older-generation collection walks again,
    ~7 % of a 20 000-path convert's CPU, and the pipeline makes few reference cycles to collect."""
    old, enabled = gc.get_threshold(), gc.isenabled()
    gc.set_threshold(*GC_THRESHOLDS)
    try:
        yield
    finally:
        gc.set_threshold(*old)
        if enabled:
            enable_promoted()  # _convert turns it off after the trace


def _convert(path: Path, outdir, settings: Settings, progress: Progress) -> Result:
    from doodlecam.trace.layout import fit_to_work_area

    path = Path(path)
    # every mistake a user can make ends here, before the slow work and before a byte is written
    checks.check_input(path)
    checks.check_settings(settings, settings.machine, [path], Path(outdir))
    timings = {}
    t0 = time.perf_counter()
    progress("tracing", 0, 0)
    drawing = trace(path, settings)
    timings["trace"] = time.perf_counter() - t0
    # After the trace the job is arrays and dataclasses without reference cycles (38 objects in cycles after
    # the trace of a 20 000-path drawing), but each collection still walks every young object: no
    # collections until the convert ends (rare_collections turns the collector on again).
    gc.disable()
    drawing_mm = select_layer(fit_to_work_area(drawing, settings.machine, settings.layout), settings.layer)
    units_in, traced = drawing.units, len(drawing.polylines)
    del drawing  # the picture's own units are not needed again: 10^5 paths hold hundreds of MB
    machine = settings.machine
    if settings.path_tolerance is not None:
        machine = replace(machine, path_tolerance=float(settings.path_tolerance))
    job = plan_job(drawing_mm, machine, settings.solver or settings.machine.solver, settings.plugin_dirs,
                   smoothing=settings.smoothing, order=settings.order, workers=settings.workers,
                   progress=progress)
    timings.update(job.meta["timings"])
    prime_splines([s.spline for s in job.strokes], lengths=True)  # the posts' lengths, at once
    for s in job.strokes:  # planned: written from the curves alone (memory at 10^5 paths)
        s.spline.forget_derivatives()
    meta = dict(drawing_mm.meta, units_in=units_in, strokes_traced=traced)
    del drawing_mm  # planned: only the job is written from here
    over = over_bounds(job)
    if over and not settings.allow_deviation:  # before any file is written
        raise PlanError(f"{path}: " + "; ".join(over) + "; nothing written (lower the speed or the tolerance "
                        "demands, or pass --allow-deviation to write it anyway)")
    job.meta["allowed_deviations"] = over
    t0 = time.perf_counter()
    progress("writing", 0, len(settings.posts))
    outputs = run_posts(job, settings)
    timings["post"] = time.perf_counter() - t0
    written = write_outputs(Path(outdir), path.stem, outputs)
    return Result(job=job, outputs=written, timings=timings, drawing_meta=meta)


def select_layer(drawing: Drawing, layer: str | None) -> Drawing:
    """Only the strokes of one layer (placed where they are in the whole drawing, so
    jobs made one layer at a time line up on the paper)."""
    if layer is None:
        return drawing
    names = drawing.layers or ("",) * len(drawing.polylines)
    if layer not in names:
        known = ", ".join(repr(n) for n in dict.fromkeys(names) if n) or "none (the drawing has one layer)"
        raise InputError(f"{drawing.source}: no layer {layer!r}; the layers are {known}")
    keep = [i for i, n in enumerate(names) if n == layer]
    return replace(drawing, polylines=tuple(drawing.polylines[i] for i in keep), layers=tuple(names[i] for i in keep))

