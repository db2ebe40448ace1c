"""The stages wired together: file -> Drawing -> Job -> output files.

Each function takes the previous stage's value and returns the next; the CLI
and the batch runner call ``convert``. Outputs are written only after every
stage and every post succeeded, each to a temporary file renamed into place,
so a failure never leaves a half-written job behind.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from doodlecam import checks, registry
from doodlecam.atomic import replace_all
from doodlecam.errors import (
    DoodleError,
    InputError,
    OutputError,
    PlanError,
    PluginError,
)
from doodlecam.machine import Machine
from doodlecam.model import Drawing, Job, Stroke
from doodlecam.options import ConvertOptions
from doodlecam.trace.raster import IMAGE_EXTENSIONS


@dataclass(frozen=True, kw_only=True)
class Settings(ConvertOptions):
    """The options of one conversion with the machine profile loaded."""

    machine: Machine


def _guarded(what: str, fn, *args):
    """Call plugin code: its own DoodleErrors pass, anything else names the plugin."""
    try:
        return fn(*args)
    except DoodleError:
        raise
    except Exception as e:
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


REPLANS = 10  # at most this many re-plans of a stroke still off the curve between samples
LOCAL_REPLANS = 3  # ... the first ones lower the jerk bound where it strays, the rest also everywhere
GLOBAL_JERK_STEP = 0.7
RAMP_REPLANS = 6  # ... and of one whose ramps pass a (nonlinear) actuator's limit
RAMP_GAIN = 1.25  # the share of a limit drops by this times the excess measured on the ramps


def plan_job(drawing: Drawing, machine: Machine, solver: str = "reach", plugin_dirs=(), order: dict | None = None,
             smoothing: float | None = None, fitted: list[Stroke] | None = None) -> Job:
    """Order, fit, plan and sample a drawing already in machine millimetres.

    ``order`` overrides the profile's [order] options (doodlecam.options.ORDER_DEFAULTS).
    ``fitted``: strokes already ordered and fitted (an edited job, e.g. from the
    studio): planned as given, without ordering or fitting ``drawing`` again.
    """
    from doodlecam.geometry.fit import fit_pieces
    from doodlecam.geometry.order import order_strokes
    from doodlecam.plan.follow import JerkBound, jerk_limit, path_deviation, ramp_ratios
    from doodlecam.plan.planner import check_profile, check_solver, plan_stroke
    from doodlecam.plan.sample import sample_stroke, whole_step_limits, written_samples
    from doodlecam.plan.travel import machine_law, make_travel, travel_time_by_law
    from doodlecam.options import order_options

    check_solver(solver)  # before the fitting, not after it
    smoothing = machine.smoothing if smoothing is None else smoothing
    kin = registry.kinematics_for(machine, plugin_dirs)
    kin.check_reachable(np.concatenate(drawing.polylines))
    timings: dict[str, float] = {}

    t0 = time.perf_counter()
    if fitted is None:
        oo = order_options({**machine.order, **(order or {})})
        # One layer after another (a pen each, in the drawing's order); strokes ordered within it.
        names = drawing.layers or ("",) * len(drawing.polylines)
        ordered = []  # (source index, polyline, layer)
        here = np.asarray(machine.home, float)
        for layer in dict.fromkeys(names):
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
    for i, p, layer in ordered if fitted is None else ():
        # a tracer may ask for its zig-zags to be cut at their corners first (joined hatching)
        for spline, err in fit_pieces(p, machine.degree, machine.tolerance, corner=float(drawing.meta.get("split_corners_deg", 0.0))):
            strokes.append(Stroke(spline=spline, source_index=i, fit_error=err, layer=layer))
    timings["fit"] = time.perf_counter() - t0

    # Between sample instants the PLC's ramps stray from the curve where its turning
    # changes fast (docs/sampling.md): with a path tolerance the planner bounds the
    # pen's jerk across the path and the sampler pulls the pen onto the curve there too.
    path_tol = machine.path_tolerance
    jerk = JerkBound(jerk_limit(path_tol, machine.delta_time)) if path_tol > 0 else None
    steps = (machine.x.steps_per_mm, machine.y.steps_per_mm)
    # Each layer is drawn with its pen, which may cap speed and acceleration below the machine's.
    pen_of = machine.pen_assignment([s.layer for s in strokes], drawing.meta.get("layer_colours"))
    by_pen = {k: pen_limits(machine, machine.pen_number(k), kin) for k in sorted(set(pen_of.values()))}
    # planned within what whole-step rounding leaves, so the samples (which keep
    # that, sample.whole_step_limits) need no extra periods to follow the plan
    by_pen = {k: (lim, whole_step_limits(lim, steps, machine.delta_time)) for k, lim in by_pen.items()}
    stroke_limits = [by_pen[pen_of[s.layer]] for s in strokes]  # (limits, plan limits) per stroke
    nonlinear = kin.linear_map is None

    # Nonlinear kinematics: the samples are pen motion, and the cranks follow its
    # constant-acceleration periods with varying acceleration. The sampler keeps the
    # cranks' velocity at the instants and their mean acceleration over each period
    # within shares of the limits (sample._crank_rows); the variation inside a period
    # comes on top. Where the executed ramps still pass a limit by e, the share drops
    # by RAMP_GAIN e and the stroke is planned within the same shares: the variation
    # is bounded by the kinematics' second derivatives times the motion, which only
    # slows, so the new peak is at most share - RAMP_GAIN e + (1 + e - share) < 1.
    scale = [(1.0, 1.0)] * len(strokes)  # per stroke: shares (velocity, acceleration) of the actuator limits
    ramps = [0.0] * len(strokes)  # per stroke: worst actuator ratio along the sampled ramps (nonlinear)

    def plan_one(n: int, s: Stroke, jerk_max, grid=None):
        limits, plan_limits = stroke_limits[n - 1]
        sv, sa = scale[n - 1]
        lim = plan_limits if sv == sa == 1.0 else replace(plan_limits, vmax=plan_limits.vmax * sv,
                                                          amax=plan_limits.amax * sa)
        try:
            prof = plan_stroke(s.spline, lim, solver=solver, smoothing=smoothing, jerk_max=jerk_max, grid=grid,
                               jerk_period=machine.delta_time)
        except PlanError as e:
            raise PlanError(f"stroke {n} of {len(strokes)}: {e}") from None
        return replace(s, profile=prof), check_profile(s.spline, prof, limits)

    def sample(s: Stroke, n: int):
        return sample_stroke(s, machine.delta_time, stroke_limits[n - 1][0], steps, follow=jerk is not None,
                             crank_share=scale[n - 1] if nonlinear else None)

    def sample_one(s: Stroke, n: int, jerk_max):
        """Samples and the per-period path deviation of stroke n (planned as s);
        for nonlinear kinematics re-plans it (into planned[n - 1]) until the
        actuators keep their limits along the sampled ramps."""
        smp = sample(s, n)
        limits = stroke_limits[n - 1][0]
        for attempt in range(RAMP_REPLANS + 1 if nonlinear else 0):
            ra, rv = ramp_ratios(written_samples(smp, steps), kin, limits.vmax, limits.amax)
            ramps[n - 1] = max(ra, rv)
            if ra <= 1.0 and rv <= 1.0:
                break
            if attempt == RAMP_REPLANS:
                raise PlanError(f"stroke {n} of {len(strokes)}: velocity samples every {machine.delta_time * 1000:g} ms "
                                "cannot keep the actuators within their limits; use a shorter [sampling] delta_time")
            sv, sa = scale[n - 1]
            step = lambda e: 0.0 if e <= 0 else max(RAMP_GAIN * e, 1e-3)  # noqa: E731
            scale[n - 1] = (max(sv - step(rv - 1.0), 0.1), max(sa - step(ra - 1.0), 0.1))
            s, ratios[n - 1] = plan_one(n, strokes[n - 1], jerk_max, s.profile.u)
            planned[n - 1] = s
            smp = sample(s, n)
        return smp, path_deviation(s.spline, written_samples(smp, steps))  # what the machine draws

    t0 = time.perf_counter()
    planned, ratios = map(list, zip(*(plan_one(n, s, jerk) for n, s in enumerate(strokes, 1)))) if strokes else ([], [])
    timings["plan"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    samples, devs = map(list, zip(*(sample_one(s, n, jerk) for n, s in enumerate(list(planned), 1)))) if planned else ([], [])
    replanned = 0
    for i in range(len(planned)):
        bound = jerk
        for attempt in range(REPLANS if jerk is not None else 0):  # still off: lower the bound where it strays
            if devs[i].max(initial=0.0) <= path_tol:
                break
            bound = bound.tightened(samples[i], devs[i], path_tol)
            if attempt >= LOCAL_REPLANS:
                # the sampler solves for the whole stroke, so a long one can stray somewhere
                # new after each local change; the swing grows with the jerk everywhere, so
                # lowering the whole bound geometrically ends it
                bound = replace(bound, base=bound.base * GLOBAL_JERK_STEP)
            planned[i], ratios[i] = plan_one(i + 1, strokes[i], bound, planned[i].profile.u)
            samples[i], devs[i] = sample_one(planned[i], i + 1, bound)
            replanned += 1
    samples = tuple(samples)
    timings["sample"] = time.perf_counter() - t0
    worst_acc = max((r[0] for r in ratios), default=0.0)
    worst_vel = max((r[1] for r in ratios), default=0.0)
    between = max((float(d.max(initial=0.0)) for d in devs), default=0.0)

    points = [np.asarray(machine.home, float)]
    for s in planned:
        points += [s.spline.start, s.spline.end]
    points.append(np.asarray(machine.home, float))
    travels = tuple(make_travel(points[2 * i], points[2 * i + 1], machine) for i in range(len(planned) + 1))
    meta = {
        "travel_law": machine_law(machine),
        "travel_time_by_law": travel_time_by_law(travels, machine),
        "solver": solver,
        "worst_acceleration_ratio": worst_acc,
        "worst_velocity_ratio": worst_vel,
        "max_fit_error_mm": max((s.fit_error for s in planned), default=0.0),
        "max_between_samples_mm": between,
        "path_tolerance_mm": path_tol,
        "strokes_replanned": replanned,
        "strokes_slowed_for_ramps": sum(1 for c in scale if min(c) < 1.0),
        "worst_ramp_ratio": max(ramps, default=0.0) if nonlinear else None,
        "control_points": sum(len(s.spline.control) for s in planned),
        "layer_colours": dict(drawing.meta.get("layer_colours", {})),
        "timings": timings,
    }
    return Job(machine=machine, strokes=tuple(planned), travels=travels, samples=samples,
               source=drawing.source, meta=meta)


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
            "max_fit_error_mm": round(j.meta["max_fit_error_mm"], 4),
            "max_between_samples_mm": round(j.meta.get("max_between_samples_mm", 0.0), 4),
            "path_tolerance_mm": j.meta.get("path_tolerance_mm", 0.0),
            "strokes_replanned": j.meta.get("strokes_replanned", 0),
            "strokes_slowed_for_ramps": j.meta.get("strokes_slowed_for_ramps", 0),
            "worst_ramp_ratio": (None if j.meta.get("worst_ramp_ratio") is None
                                 else round(j.meta["worst_ramp_ratio"], 6)),
            "worst_acceleration_ratio": round(j.meta["worst_acceleration_ratio"], 9),
            "worst_velocity_ratio": round(j.meta["worst_velocity_ratio"], 9),
            "travel_law": j.meta.get("travel_law", ""),
            "travel_time_by_law_s": {k: round(v, 3) for k, v in j.meta.get("travel_time_by_law", {}).items()},
            "outputs": [str(p) for p in self.outputs],
            "grbl_estimate_s": self.grbl_estimate(),
            "timings_s": {k: round(v, 3) for k, v in self.timings.items()},
            "layers": [n for n in j.layers if n] or [],
            "pen_changes": len(j.pen_changes),
            "pens": {n: j.machine.pen_number(k).describe(k) for n, k in j.layer_pens.items() if n},
        }


def convert(path: str | Path, outdir: str | Path, settings: Settings) -> Result:
    from doodlecam.trace.layout import fit_to_work_area

    path = Path(path)
    # every mistake a user can make ends here, before the slow work and before a byte is written
    checks.check_input(path)
    checks.check_settings(settings, settings.machine, [path], Path(outdir))
    timings = {}
    t0 = time.perf_counter()
    drawing = trace(path, settings)
    timings["trace"] = time.perf_counter() - t0
    drawing_mm = select_layer(fit_to_work_area(drawing, settings.machine, settings.layout), settings.layer)
    machine = settings.machine
    if settings.path_tolerance is not None:
        machine = replace(machine, path_tolerance=float(settings.path_tolerance))
    job = plan_job(drawing_mm, machine, settings.solver or settings.machine.solver, settings.plugin_dirs,
                   smoothing=settings.smoothing,
                   order=settings.order)
    timings.update(job.meta["timings"])
    over = over_bounds(job)
    if over and not settings.allow_deviation:  # before any file is written
        raise PlanError(f"{path}: " + "; ".join(over) + "; nothing written (lower the speed or the tolerance "
                        "demands, or pass --allow-deviation to write it anyway)")
    job.meta["allowed_deviations"] = over
    t0 = time.perf_counter()
    outputs = run_posts(job, settings)
    timings["post"] = time.perf_counter() - t0
    written = write_outputs(Path(outdir), path.stem, outputs)
    meta = dict(drawing_mm.meta, units_in=drawing.units, strokes_traced=len(drawing.polylines))
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

