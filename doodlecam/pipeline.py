"""The stages wired together: file -> Drawing -> Job -> output files.

Each function takes the previous stage's value and returns the next; the CLI
and the batch runner call ``convert``. Outputs are written only after every
stage and every post succeeded, each to a temporary file renamed into place,
so a failure never leaves a half-written job behind.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from doodlecam import registry
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
    if settings.tracer:
        return registry.get("tracer", settings.tracer, settings.plugin_dirs)
    ext = path.suffix.lower()
    candidates = [i for i in registry.discover(settings.plugin_dirs) if i.kind == "tracer"]
    candidates.sort(key=lambda i: i.name != "edges")  # the report's tracer first for pictures
    for info in candidates:
        try:
            cls = info.load()
        except PluginError:
            continue
        if ext in cls.extensions:
            return cls
    raise InputError(f"{path}: no tracer reads '{ext or 'files without extension'}' files; give a picture (PNG, JPEG, ...) or pick one with --tracer")


def trace(path: Path, settings: Settings) -> Drawing:
    if not path.exists():
        raise InputError(f"{path}: no such file; check the path")
    if path.is_dir():
        raise InputError(f"{path}: is a folder; give one file (folders are for 'doodlecam batch')")
    cls = pick_tracer(path, settings)
    opts = cls.resolve_options(settings.machine.plugin_options.get(f"trace.{cls.name}", {}), settings.tracer_options)
    drawing = _guarded(f"tracer '{cls.name}' on {path}", cls().trace, path, opts)
    if not isinstance(drawing, Drawing):
        raise PluginError(f"tracer '{cls.name}' returned {type(drawing).__name__}, not a Drawing; fix the plugin")
    return drawing


REPLANS = 4  # at most this many re-plans of a stroke still off the curve between samples
RAMP_REPLANS = 3  # ... and of one whose ramps pass a (nonlinear) actuator's limit


def plan_job(drawing: Drawing, machine: Machine, solver: str = "reach", plugin_dirs=(), order: dict | None = None,
             smoothing: float | None = None, fitted: list[Stroke] | None = None) -> Job:
    """Order, fit, plan and sample a drawing already in machine millimetres.

    ``order`` overrides the profile's [order] options (doodlecam.trace.layout.ORDER_DEFAULTS).
    ``fitted``: strokes already ordered and fitted (an edited job, e.g. from the
    studio): planned as given, without ordering or fitting ``drawing`` again.
    """
    from doodlecam.geometry.fit import fit_pieces
    from doodlecam.geometry.order import order_strokes
    from doodlecam.plan.follow import JerkBound, jerk_limit, path_deviation, ramp_ratios
    from doodlecam.plan.planner import Limits, check_profile, check_solver, plan_stroke
    from doodlecam.plan.sample import sample_stroke
    from doodlecam.plan.travel import machine_law, make_travel, travel_time_by_law
    from doodlecam.options import order_options

    check_solver(solver)  # before the fitting, not after it
    smoothing = machine.smoothing if smoothing is None else smoothing
    kin = registry.kinematics_for(machine, plugin_dirs)
    kin.check_reachable(np.concatenate(drawing.polylines))
    limits = Limits.from_machine(machine, kin)
    timings: dict[str, float] = {}

    t0 = time.perf_counter()
    if fitted is None:
        oo = order_options({**machine.order, **(order or {})})
        ordered = order_strokes(drawing.polylines, machine.home, allow_reverse=oo["reverse"],
                                merge=oo["merge"], budget=oo["budget"])
    timings["order"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    strokes = [] if fitted is None else [Stroke(spline=s.spline, source_index=s.source_index, fit_error=s.fit_error)
                                         for s in fitted]
    for i, p in zip(ordered.source, ordered.polylines) if fitted is None else ():
        for spline, err in fit_pieces(p, machine.degree, machine.tolerance):
            strokes.append(Stroke(spline=spline, source_index=i, fit_error=err))
    timings["fit"] = time.perf_counter() - t0

    # Between sample instants the PLC's ramps stray from the curve where its turning
    # changes fast (docs/sampling.md): with a path tolerance the planner bounds the
    # pen's jerk across the path and the sampler pulls the pen onto the curve there too.
    path_tol = machine.path_tolerance
    jerk = JerkBound(jerk_limit(path_tol, machine.delta_time)) if path_tol > 0 else None
    steps = (machine.x.steps_per_mm, machine.y.steps_per_mm)

    # Nonlinear kinematics: the samples are pen motion, and the cranks follow its
    # constant-acceleration periods with varying acceleration that can pass their
    # limit by a few per cent. Such a stroke is planned again within lower limits.
    nonlinear = limits.M is None
    scale = [1.0] * len(strokes)  # per stroke: the share of the actuator limits planned with
    ramps = [0.0] * len(strokes)  # per stroke: worst actuator ratio along the sampled ramps (nonlinear)

    def plan_one(n: int, s: Stroke, jerk_max, grid=None):
        lim = limits if scale[n - 1] == 1.0 else replace(limits, vmax=limits.vmax * np.sqrt(scale[n - 1]),
                                                         amax=limits.amax * scale[n - 1])
        try:
            prof = plan_stroke(s.spline, lim, solver=solver, smoothing=smoothing, jerk_max=jerk_max, grid=grid)
        except PlanError as e:
            raise PlanError(f"stroke {n} of {len(strokes)}: {e}") from None
        return replace(s, profile=prof), check_profile(s.spline, prof, limits)

    def sample_one(s: Stroke, n: int, jerk_max):
        """Samples and the per-period path deviation of stroke n (planned as s);
        for nonlinear kinematics re-plans it (into planned[n - 1]) until the
        actuators keep their limits along the sampled ramps."""
        smp = sample_stroke(s, machine.delta_time, limits, steps, follow=jerk is not None)
        for attempt in range(RAMP_REPLANS + 1 if nonlinear else 0):
            ra, rv = ramp_ratios(smp, kin, limits.vmax, limits.amax)
            ramps[n - 1] = max(ra, rv)
            r = max(ra, rv * rv)  # a slower plan: accelerations scale with the square of speeds
            if r <= 1.0:
                break
            if attempt == RAMP_REPLANS:
                raise PlanError(f"stroke {n} of {len(strokes)}: velocity samples every {machine.delta_time * 1000:g} ms "
                                "cannot keep the actuators within their limits; use a shorter [sampling] delta_time")
            scale[n - 1] *= 0.98 / r
            s, ratios[n - 1] = plan_one(n, strokes[n - 1], jerk_max, s.profile.u)
            planned[n - 1] = s
            smp = sample_stroke(s, machine.delta_time, limits, steps, follow=jerk is not None)
        return smp, path_deviation(s.spline, smp)

    t0 = time.perf_counter()
    planned, ratios = map(list, zip(*(plan_one(n, s, jerk) for n, s in enumerate(strokes, 1)))) if strokes else ([], [])
    timings["plan"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    samples, devs = map(list, zip(*(sample_one(s, n, jerk) for n, s in enumerate(list(planned), 1)))) if planned else ([], [])
    replanned = 0
    for i in range(len(planned)):
        bound = jerk
        for _ in range(REPLANS if jerk is not None else 0):  # still off: lower the bound where it strays
            if devs[i].max(initial=0.0) <= path_tol:
                break
            bound = bound.tightened(samples[i], devs[i], path_tol)
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
        "strokes_slowed_for_ramps": sum(1 for c in scale if c < 1.0),
        "worst_ramp_ratio": max(ramps, default=0.0) if nonlinear else None,
        "control_points": sum(len(s.spline.control) for s in planned),
        "timings": timings,
    }
    return Job(machine=machine, strokes=tuple(planned), travels=travels, samples=samples,
               source=drawing.source, meta=meta)


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


@dataclass
class Result:
    job: Job
    outputs: list[Path]
    timings: dict[str, float]

    def summary(self) -> dict[str, Any]:
        j = self.job
        return {
            "source": j.source,
            "machine": j.machine.name,
            "strokes": len(j.strokes),
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
            "timings_s": {k: round(v, 3) for k, v in self.timings.items()},
        }


def convert(path: str | Path, outdir: str | Path, settings: Settings) -> Result:
    from doodlecam.trace.layout import fit_to_work_area

    path = Path(path)
    timings = {}
    t0 = time.perf_counter()
    drawing = trace(path, settings)
    timings["trace"] = time.perf_counter() - t0
    drawing_mm = fit_to_work_area(drawing, settings.machine, settings.layout)
    machine = settings.machine
    if settings.path_tolerance is not None:
        machine = replace(machine, path_tolerance=float(settings.path_tolerance))
    job = plan_job(drawing_mm, machine, settings.solver or settings.machine.solver, settings.plugin_dirs,
                   smoothing=settings.smoothing,
                   order=settings.order)
    timings.update(job.meta["timings"])
    t0 = time.perf_counter()
    outputs = run_posts(job, settings)
    timings["post"] = time.perf_counter() - t0
    written = write_outputs(Path(outdir), path.stem, outputs)
    return Result(job=job, outputs=written, timings=timings)
