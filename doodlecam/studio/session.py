"""The studio's state: one loaded file, its traced drawing and the (edited) planned job.

Every stage is the CLI's: ``pipeline.trace`` -> ``trace.layout.fit_to_work_area``
-> ``pipeline.plan_job`` -> ``pipeline.run_posts``. An edit changes strokes'
control points; only the changed strokes are planned again (``plan_job`` with
``fitted=``), the others keep their plans, so the job equals what planning the
whole edited job would give. Units: mm and s.
"""

from __future__ import annotations

import json
import secrets
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from doodlecam import registry
from doodlecam.errors import DoodleError, InputError
from doodlecam.model import Drawing, Job, Spline, Stroke
from doodlecam.pipeline import Settings, plan_job, run_posts, trace
from doodlecam.plan.travel import make_travel, travel_time_by_law

JOB_FORMAT = "doodlecam-studio-job"
JOB_VERSION = 1
HISTORY = 100  # undo steps kept
# an edited job's largest figures (meta), by the studio's checks of its strokes
WORST = ("worst_acceleration_ratio", "worst_velocity_ratio", "max_between_samples_mm", "max_fit_error_mm")
# a drawing of this many traced paths or more is planned in the background: the page shows its paths at once
# and follows the planning through the event stream (planning is ~1.5 ms of CPU a stroke)
BACKGROUND_MIN = 1000


def _settings_machine(settings: Settings):
    m = settings.machine
    return m if settings.path_tolerance is None else replace(m, path_tolerance=float(settings.path_tolerance))


class StaleEdit(InputError):
    """An edit made on a view the job has moved on from (another tab, another file)."""


class _Superseded(Exception):
    """Raised from a background plan's progress when another load replaced its drawing."""


class Session:
    """One user's job. Methods raise DoodleErrors (one line each) on bad input."""

    def __init__(self, settings: Settings, max_upload: int = 20 << 20):
        self.settings = settings
        self.machine = _settings_machine(settings)
        self.max_upload = max_upload
        self.lock = threading.RLock()  # requests run in a thread pool
        # the job's id, version and planning change together: event() reads them under this (never
        # under self.lock, which a change holds while it wakes the event streams)
        self._state_lock = threading.Lock()
        self.name = ""
        self.data = b""
        self.tracer: str | None = settings.tracer
        self.tracer_options: dict[str, Any] = dict(settings.tracer_options)
        self.job: Job | None = None
        self.undo_stack: list[Job] = []
        self.redo_stack: list[Job] = []
        self._checks: dict[int, tuple] = {}  # id(stroke) -> (stroke, acc ratio, vel ratio, deviation per period), cached
        self._worst_of: tuple | None = None  # (job, its WORST figures by these checks), for the next edit
        self._views: dict[int, tuple] = {}  # id(stroke) -> (stroke, samples, its /api/view entry without "i"), cached
        self.last_changed: tuple[int, ...] = ()  # strokes the last edit re-planned (the count of strokes unchanged)
        # every job gets a fresh id and every change a new version: an edit made on an older view (another tab
        # opened another file, or changed this one) is refused instead of being applied to a job it was not made on
        self.job_id = ""
        self.version = 0
        # a large drawing is shown as traced (``preview``, mm) while it is planned in the background;
        # ``planning``: {"stage", "done", "total"} meanwhile, {"error": ...} if it failed, else None
        self.preview: Drawing | None = None
        self.planning: dict | None = None
        self._generation = 0  # bumped by every load: a superseded background plan stops
        self._totals: tuple | None = None  # (job, the job-wide part of its summary), computed once per job
        self.listeners: list = []  # called (no arguments) on every change an open page follows
        self._previewed = threading.Event()  # the preview was sent: the background plan may take the CPU

    # ------------------------------------------------------------ tracers

    def tracers(self) -> list[dict[str, Any]]:
        """Every tracer plugin with its declared options: the page builds its panel from these."""
        out = []
        for info in registry.discover(self.settings.plugin_dirs):
            if info.kind != "tracer":
                continue
            try:
                cls = info.load()
            except DoodleError:
                continue
            out.append({"name": cls.name, "extensions": list(cls.extensions), 
                        "options": [{"name": o.name, "type": o.type.__name__, "default": o.default, "help": o.help,
                                     "choices": list(o.choices) if o.choices else None} for o in cls.options]})
        return sorted(out, key=lambda t: t["name"])

    # ------------------------------------------------------------ load, trace, plan

    def load(self, name: str, data: bytes, tracer: str | None = None, options: dict[str, Any] | None = None,
             background: bool | None = None) -> dict:
        """Trace and plan an uploaded file (kept in memory; traced from a private temporary copy).

        ``background``: answer once traced and plan in a thread (the summary then has ``planning``);
        by default for drawings of BACKGROUND_MIN paths or more. Tracing errors are raised either way."""
        name = Path(name or "").name
        if not name or name in (".", "..") or "\x00" in name:
            raise InputError("the upload has no file name; pick a file")
        if len(data) > self.max_upload:
            raise InputError(f"{name}: {len(data) / 1e6:.1f} MB is larger than the studio's limit of "
                             f"{self.max_upload / 1e6:.0f} MB; start it with a larger --max-upload")
        if not data:
            raise InputError(f"{name}: the file is empty; pick another")
        # the slow part runs without the session lock: the view, the state and a send's controls keep answering
        drawing = self._trace(name, data, tracer, options or {})
        later = len(drawing.polylines) >= BACKGROUND_MIN if background is None else background
        job = None if later else self._plan(drawing)
        with self.lock:
            self.name, self.data = name, data
            self.tracer, self.tracer_options = tracer, dict(options or {})
            self._generation += 1
            self._checks.clear()
            self._worst_of = None
            self._views.clear()
            self._previewed.clear()
            preview, planning = (drawing, {"stage": "ordering", "done": 0, "total": len(drawing.polylines)}) \
                if later else (None, None)
            self._set(job, keep_history=False, preview=preview, planning=planning)
            if later:
                threading.Thread(target=self._plan_later, args=(drawing, self._generation), name="studio-plan",
                                 daemon=True).start()
            else:
                self._check_later(job)
            return self.summary()

    def _plan_later(self, drawing: Drawing, generation: int) -> None:
        """Plan a loaded drawing in the background, telling the pages its progress (at most 5 times a
        second); the planned job replaces the preview unless another load came first."""
        last = [0.0]

        def progress(stage: str, done: int, total: int) -> None:
            if self._generation != generation:
                raise _Superseded  # stops plan_job: its drawing is no longer the studio's
            now = time.monotonic()
            if now - last[0] >= 0.2 or done == total:
                last[0] = now
                self.planning = {"stage": stage, "done": done, "total": total}
                self._notify()

        # the page's first view (its request, then the preview's JSON) comes before the plan, which would
        # share the interpreter with it; a page that never asks waits at most a second
        self._previewed.wait(1.0)
        try:
            job = self._plan(drawing, progress)
            for st, sa in zip(job.strokes, job.samples):  # the page's view of it, before it is asked for
                self._stroke_arrays(st, sa, len(job.strokes))
        except _Superseded:
            return
        except Exception as e:  # a DoodleError is the user's one line; anything else is a bug, said as such
            with self.lock:
                if self._generation == generation:
                    msg = str(e) if isinstance(e, DoodleError) else f"internal error: {type(e).__name__}: {e}"
                    with self._state_lock:
                        self.planning = {"error": msg}
                        self.version += 1
                    self._notify()
            return
        with self.lock:
            if self._generation != generation:
                return
            self._set(job, keep_history=False, preview=None, planning=None)
            self._check_later(job)

    def _notify(self) -> None:
        for f in list(self.listeners):
            f()

    def event(self) -> dict:
        """What an open page follows: the job and its version, and the planning's progress."""
        with self._state_lock:
            return {"job": self.job_id, "version": self.version, "planning": self.planning}

    def _check_later(self, job: Job) -> None:
        """Each stroke's checks, in the background, and the job's largest figures by them: the first edit
        then only checks its own."""
        generation = self._generation

        def run():
            for st, sa in zip(job.strokes, job.samples):
                if self._generation != generation:
                    return  # superseded by another load
                self.checks(st, sa)
            with self.lock:
                if self.job is job:
                    self._worst(job.strokes, job.samples, job)

        threading.Thread(target=run, name="studio-check", daemon=True).start()

    def retrace(self, tracer: str | None, options: dict[str, Any]) -> dict:
        with self.lock:
            name, data = self.name, self.data
        if not data:
            raise InputError("no file is loaded; open a picture or vector file first")
        return self.load(name, data, tracer, options)

    def _trace(self, name: str, data: bytes, tracer: str | None, options: dict[str, Any]) -> Drawing:
        """The upload traced and laid out in the work area (mm): what the preview shows and plan_job plans."""
        from doodlecam.trace.layout import fit_to_work_area

        settings = replace(self.settings, tracer=tracer or None, tracer_options=options)
        with tempfile.TemporaryDirectory(prefix="doodlecam-studio-") as tmp:
            path = Path(tmp) / name
            path.write_bytes(data)
            try:
                drawing = trace(path, settings)
            except DoodleError as e:  # the message names the upload, not the private copy
                e.args = (str(e).replace(str(path), name),)
                raise
        drawing = replace(drawing, source=name)
        mm = fit_to_work_area(drawing, settings.machine, settings.layout)
        if not mm.polylines:
            raise InputError(f"{name}: nothing to draw with these tracer options; loosen them (e.g. a lower threshold)")
        meta = {**mm.meta, "tracer_made": drawing.meta.get("made")}
        if drawing.meta.get("format") == "mesh":  # the STL panel: the mesh's extent and where it was cut
            meta["mesh"] = {k: drawing.meta[k] for k in ("bounds_mm", "plane", "level_mm", "span_mm", "direction")
                            if k in drawing.meta}
        return replace(mm, meta=meta)

    def _plan(self, mm: Drawing, progress=None) -> Job:
        s = self.settings
        kw = {"progress": progress} if progress is not None else {}
        job = plan_job(mm, self.machine, s.solver or self.machine.solver, s.plugin_dirs,
                       smoothing=s.smoothing, order=s.order, **kw)
        job.meta["tracer_made"] = mm.meta.get("tracer_made")  # the tracer's line on what it drew, for the page
        job.meta["mesh"] = mm.meta.get("mesh")
        return job

    def _require(self) -> Job:
        if self.job is None:
            p = self.planning
            if p and "error" in p:
                raise InputError(f"planning failed: {p['error']}")
            if p:
                raise InputError(f"the job is still being planned ({p['stage']} {p['done']} of {p['total']}); "
                                 "wait for it to finish")
            raise InputError("no job yet; open a picture or vector file first")
        return self.job

    # ------------------------------------------------------------ edits

    def _plan_strokes(self, strokes: list[Stroke]) -> tuple[list[Stroke], list]:
        """Plan strokes (already fitted and ordered) with the job's settings: (planned, samples)."""
        if not strokes:
            return [], []
        s = self.settings
        drawing = _curves(strokes)
        job = self._require()  # its strokes keep the pens the whole job gave their layers
        why = job.meta.get("pen_reasons") or {}
        pens = {n: (int(k), why.get(n, "")) for n, k in job.layer_pens.items()}
        job = plan_job(drawing, self.machine, s.solver or self.machine.solver, s.plugin_dirs,
                       smoothing=s.smoothing, fitted=strokes, pens=pens)
        return list(job.strokes), list(job.samples)

    def _rebuild(self, strokes: list[Stroke], samples: list, changed: set[int]) -> Job:
        """The job with ``strokes`` in this order, re-planning those at ``changed``. Everything else is
        kept: a 10 000-stroke job re-plans one stroke, two travels and a few sums (no Python work per
        stroke beyond a lookup), so an edit costs what its own strokes cost."""
        idx = sorted(changed)
        planned, smp = self._plan_strokes([strokes[i] for i in idx])
        for i, st, sa in zip(idx, planned, smp):
            strokes[i], samples[i] = st, sa
        old = self._require()
        if idx and len(strokes) == len(old.strokes):  # the strokes at idx replaced, the others where they were
            return self._replacing(old, {i: (strokes[i], samples[i]) for i in idx})
        travels, new_t, gone = self._keep_travels(old, strokes)
        by_law = old.meta.get("travel_time_by_law")
        by_law = travel_time_by_law(travels, self.machine) if by_law is None or len(new_t) + len(gone) > len(travels) \
            else self._by_law(by_law, gone, new_t)
        meta = {**old.meta, "control_points": sum(len(st.spline.control) for st in strokes),
                **dict(zip(WORST, self._worst(strokes, samples))), "travel_time_by_law": by_law, "edited": True}
        return replace(old, strokes=tuple(strokes), samples=tuple(samples), travels=travels, meta=meta)

    def _replacing(self, old: Job, repl: dict[int, tuple]) -> Job:
        """_rebuild for strokes replaced in place (a drag, an inserted point, a reversal...): only their
        travels, checks and the job's totals by the differences (Job.replacing), so that an edit of one
        stroke of 10^5 costs what that stroke costs, not a pass over all of them."""
        home, n = np.asarray(self.machine.home, float), len(old.strokes)

        def stroke(k: int) -> Stroke:
            return repl[k][0] if k in repl else old.strokes[k]

        def figures(st: Stroke, sa) -> tuple:  # as _worst takes them
            acc, vel, _, between = self.checks(st, sa)
            return acc, vel, between, st.fit_error

        travels = {}
        for t in sorted({k for i in repl for k in (i, i + 1)}):  # a travel whose ends did not move is kept
            start, end = stroke(t - 1).spline.end if t else home, stroke(t).spline.start if t < n else home
            was = old.travels[t]
            if not (np.array_equal(was.start, start) and np.array_equal(was.end, end)):
                travels[t] = make_travel(start, end, self.machine)
        worst = self._worst(old.strokes, old.samples, old)
        before = [figures(old.strokes[i], old.samples[i]) for i in repl]
        after = [figures(st, sa) for st, sa in repl.values()]
        if any(max(f[k] for f in before) >= w > max(f[k] for f in after) for k, w in enumerate(worst)):
            # an edited stroke held a largest figure, now lower: over every stroke again
            strokes, samples = list(old.strokes), list(old.samples)
            for i, (st, sa) in repl.items():
                strokes[i], samples[i] = st, sa
            worst = self._worst(strokes, samples)
        else:
            worst = tuple(max(w, *(f[k] for f in after)) for k, w in enumerate(worst))
        cp = old.meta.get("control_points")
        cp = sum(len(s.spline.control) for s in old.strokes) if cp is None else cp
        cp += sum(len(st.spline.control) - len(old.strokes[i].spline.control) for i, (st, _) in repl.items())
        by_law = old.meta.get("travel_time_by_law")
        if by_law is not None:
            by_law = self._by_law(by_law, [old.travels[t] for t in travels], list(travels.values()))
        meta = {**old.meta, "control_points": cp, **dict(zip(WORST, worst)), "travel_time_by_law": by_law,
                "edited": True}
        job = old.replacing(repl, travels, meta)
        if by_law is None:
            meta["travel_time_by_law"] = travel_time_by_law(job.travels, self.machine)
        self._worst_of = (job, worst)
        return job

    def _worst(self, strokes, samples, job: Job | None = None) -> tuple[float, float, float, float]:
        """The largest acceleration and velocity ratios, distance between samples and fit error over these
        strokes (WORST), by the session's checks; ``job``: they are its strokes (remembered for the next edit)."""
        if job is not None and self._worst_of is not None and self._worst_of[0] is job:
            return self._worst_of[1]
        get = self._checks.get
        checks = [get(id(st)) for st in strokes]
        checks = [c[1:] if c is not None and c[0] is st else self.checks(st, sa)
                  for c, st, sa in zip(checks, strokes, samples)]
        worst = (max((c[0] for c in checks), default=0.0), max((c[1] for c in checks), default=0.0),
                 max((c[3] for c in checks), default=0.0), max((st.fit_error for st in strokes), default=0.0))
        if job is not None:
            self._worst_of = (job, worst)
        return worst

    def _by_law(self, by_law: dict[str, float], gone: list, new: list) -> dict[str, float]:
        """The travel time by law (s) of a job: another's, less the travels gone, plus the new ones."""
        minus, plus = travel_time_by_law(gone, self.machine), travel_time_by_law(new, self.machine)
        return {law: v - minus[law] + plus[law] for law, v in by_law.items()}

    def _keep_travels(self, old: Job, strokes: list[Stroke]) -> tuple[tuple, list, list]:
        """(travels, the new ones, the old ones gone) for ``strokes``: a travel between two strokes that
        were neighbours in ``old`` is kept, and so is one whose ends did not move (an interior control
        point dragged); only the others are made again."""
        home = np.asarray(self.machine.home, float)
        ids = [None, *map(id, strokes), None]  # travel i leads from ids[i] (None: home) to ids[i + 1]
        was = [None, *map(id, old.strokes), None]
        by_pair = {(a, b): t for a, b, t in zip(was, was[1:], old.travels)}
        same = len(strokes) == len(old.strokes)
        used, travels, new_t = set(), [], []
        for i, pair in enumerate(zip(ids, ids[1:])):
            t = by_pair.get(pair)
            if t is None:
                start = strokes[i - 1].spline.end if i else home
                end = strokes[i].spline.start if i < len(strokes) else home
                t = old.travels[i] if same else None  # the travel at the same place, if its ends are the same
                if t is None or id(t) in used or not (np.array_equal(t.start, start) and np.array_equal(t.end, end)):
                    t = make_travel(start, end, self.machine)
                    new_t.append(t)
            used.add(id(t))
            travels.append(t)
        gone = [t for t in old.travels if id(t) not in used]
        return tuple(travels), new_t, gone

    def _travel_points(self, strokes) -> list[np.ndarray]:
        """Each travel's start and end: home, the strokes' ends and starts in order, home."""
        points = [np.asarray(self.machine.home, float)]
        for st in strokes:
            points += [st.spline.start, st.spline.end]
        points.append(np.asarray(self.machine.home, float))
        return points

    def only_layers(self, job: Job, layers: Any) -> Job:
        """The job with only ``layers`` (names), its strokes in the same order and travels between them:
        what 'plot one layer' sends and exports."""
        if not isinstance(layers, list) or not layers or not all(isinstance(n, str) for n in layers):
            raise InputError("layers must be a list of layer names, e.g. [\"red\"]")
        unknown = sorted(set(layers) - set(job.layers))
        if unknown:
            raise InputError(f"the job has no layer '{unknown[0]}'; its layers: {', '.join(job.layers) or '(one, unnamed)'}")
        keep = [i for i, st in enumerate(job.strokes) if st.layer in layers]
        strokes = [job.strokes[i] for i in keep]
        points = self._travel_points(strokes)
        travels = tuple(make_travel(points[2 * i], points[2 * i + 1], self.machine) for i in range(len(strokes) + 1))
        meta = {**job.meta, "travel_time_by_law": travel_time_by_law(travels, self.machine)}
        return replace(job, strokes=tuple(strokes), samples=tuple(job.samples[i] for i in keep), travels=travels,
                       meta=meta)

    def checks(self, stroke: Stroke, samples) -> tuple[float, float, np.ndarray, float]:
        """(acceleration, velocity) worst ratio to the limits, checked on the planner's fine grid,
        the executed path's distance from the curve per sample period (mm), as plan_job checks them, and its largest."""
        from doodlecam.plan.follow import path_deviation
        from doodlecam.plan.planner import Limits, check_profile

        hit = self._checks.get(id(stroke))
        if hit is None or hit[0] is not stroke:  # the stroke is kept in the entry, so its id is not reused
            kin = registry.kinematics_for(self.machine, self.settings.plugin_dirs)
            r = check_profile(stroke.spline, stroke.profile, Limits.from_machine(self.machine, kin))
            dev = path_deviation(stroke.spline, samples)
            hit = self._checks[id(stroke)] = (stroke, float(r[0]), float(r[1]), dev, float(dev.max(initial=0.0)))
        return hit[1:]

    def _index(self, i: Any, n: int, what: str = "stroke") -> int:
        try:
            k = int(i)
        except (TypeError, ValueError):
            raise InputError(f"{what} must be a number, got {i!r}") from None
        if not 0 <= k < n:
            raise InputError(f"{what} {k} does not exist (0 to {n - 1}); reload the page")
        return k

    def edit(self, op: str, stroke: Any = None, **kw) -> dict:
        """Apply one edit; returns the new summary. ops: move, insert, delete_point, delete, reverse, split, reorder."""
        with self.lock:
            job = self._require()
            strokes, samples = list(job.strokes), list(job.samples)
            i = self._index(stroke, len(strokes))
            st = strokes[i]
            ctrl = np.array(st.spline.control)
            deg = st.spline.degree
            changed = {i}
            if op == "move":
                try:
                    control = np.asarray(kw.get("control"), dtype=float) if kw.get("control") is not None else None
                except (TypeError, ValueError):
                    control = None
                if control is None or control.ndim != 2 or control.shape[1] != 2 or not np.isfinite(control).all():
                    raise InputError("move needs 'control': a list of [x, y] control points in mm")
                if len(control) < deg + 1:
                    raise InputError(f"a stroke needs at least {deg + 1} control points")
                if len(control) != len(ctrl):  # a move never changes their number (that is insert / delete_point)
                    raise InputError(f"move keeps the stroke's {len(ctrl)} control points (got {len(control)}); "
                                     "use insert or delete_point to change their number")
                strokes[i] = Stroke(Spline(deg, control), source_index=st.source_index, layer=st.layer)
            elif op == "insert":  # a new point halfway between control points k and k + 1
                k = self._index(kw.get("point"), len(ctrl), "control point")
                if k == len(ctrl) - 1:
                    raise InputError(f"control point {k} is the stroke's last; insert after an earlier one")
                if len(ctrl) >= MAX_STROKE_CONTROL:
                    raise InputError(f"a stroke has at most {MAX_STROKE_CONTROL} control points; refit it first")
                strokes[i] = Stroke(Spline(deg, np.insert(ctrl, k + 1, (ctrl[k] + ctrl[k + 1]) / 2, axis=0)),
                                    source_index=st.source_index, layer=st.layer)
            elif op == "delete_point":
                k = self._index(kw.get("point"), len(ctrl), "control point")
                if len(ctrl) <= deg + 1:
                    raise InputError(f"a stroke needs at least {deg + 1} control points; delete the stroke instead")
                strokes[i] = Stroke(Spline(deg, np.delete(ctrl, k, axis=0)), source_index=st.source_index, layer=st.layer)
            elif op == "delete":
                del strokes[i], samples[i]
                changed = set()
            elif op == "reverse":
                strokes[i] = Stroke(st.spline.reversed(), source_index=st.source_index, layer=st.layer)
            elif op == "split":  # at control point k: two strokes sharing it
                k = self._index(kw.get("point"), len(ctrl), "control point")
                if k < deg or len(ctrl) - k < deg + 1:
                    raise InputError(f"split at a control point with at least {deg} others on each side")
                strokes[i:i + 1] = [Stroke(Spline(deg, ctrl[:k + 1]), source_index=st.source_index, layer=st.layer),
                                    Stroke(Spline(deg, ctrl[k:]), source_index=st.source_index, layer=st.layer)]
                samples[i:i + 1] = [None, None]
                changed = {i, i + 1}
            elif op == "refit":  # fewer control points: the curve refitted within a tolerance the user sets
                tol = kw.get("tolerance")
                if not isinstance(tol, (int, float)) or isinstance(tol, bool) or not 0.001 <= tol <= 10:
                    raise InputError("refit needs 'tolerance': the largest distance from the curve, 0.001 to 10 mm")
                strokes[i] = Stroke(refit(st.spline, float(tol)), source_index=st.source_index, layer=st.layer)
            elif op == "reorder":
                to = self._index(kw.get("to"), len(strokes), "position")
                strokes.insert(to, strokes.pop(i))
                samples.insert(to, samples.pop(i))
                changed = set()
            else:
                raise InputError(f"unknown edit '{op}'; use move, insert, delete_point, delete, reverse, split, refit "
                                 "or reorder")
            for n in changed:  # the edited curves, checked as a saved job's are, before any planning
                check_spline(strokes[n].spline, self.machine, f"stroke {n}")
            self._set(self._rebuild(strokes, samples, changed))
            self.last_changed = tuple(sorted(changed)) if len(strokes) == len(job.strokes) else ()
            return self.summary()

    def expect(self, job_id: Any, version: Any) -> None:
        """Refuse a change made on a view of another job or of an older version of this one."""
        if job_id != self.job_id or version != self.version:
            raise StaleEdit("the job changed in another tab; reload")

    def _set(self, job: Job, keep_history: bool = True, **state) -> None:
        """Make ``job`` the current one (a new job id unless ``keep_history``), with the other ``state``
        attributes given (preview, planning) changed at the same moment for event()."""
        with self._state_lock:
            for name, value in state.items():
                setattr(self, name, value)
            self.version += 1
            if not keep_history:
                self.job_id = secrets.token_hex(6)
        if keep_history and self.job is not None:
            self.undo_stack = (self.undo_stack + [self.job])[-HISTORY:]
        elif not keep_history:
            self.undo_stack = []
        self.redo_stack = []
        self.job = job
        self._notify()

    def undo(self) -> dict:
        return self._step(self.undo_stack, self.redo_stack, "undo")

    def redo(self) -> dict:
        return self._step(self.redo_stack, self.undo_stack, "redo")

    def _step(self, source: list[Job], other: list[Job], what: str) -> dict:
        with self.lock:
            if not source:
                raise InputError(f"nothing to {what}")
            other.append(self._require())
            self.job = source.pop()
            self.version += 1
            self._notify()
            return self.summary()

    # ------------------------------------------------------------ views

    def summary(self) -> dict:
        """The job's figures, with its id and version (and, while it is planned, the traced drawing's)."""
        if self.job is None and self.preview is not None:
            d = self.preview
            if self._totals is None or self._totals[0] is not d:
                ink = float(sum(np.hypot(*np.diff(p, axis=0).T).sum() for p in d.polylines))
                self._totals = (d, {"strokes": len(d.polylines), "control_points": 0, "pen_down_mm": round(ink, 3),
                                    "travel_mm": 0.0, "job_time_s": 0.0, "draw_time_s": 0.0,
                                    "worst_acceleration_ratio": 0.0, "worst_velocity_ratio": 0.0,
                                    "tracer_made": d.meta.get("tracer_made"), "mesh": d.meta.get("mesh")})
        else:
            job = self._require()
            if self._totals is None or self._totals[0] is not job:  # once per job: a summary is asked for often
                self._totals = (job, {
                    "strokes": len(job.strokes), "control_points": job.meta.get("control_points") or sum(
                        len(s.spline.control) for s in job.strokes),
                    "pen_down_mm": round(job.pen_down_length, 3), "travel_mm": round(job.travel_length, 3),
                    "job_time_s": round(job.duration, 3), "draw_time_s": round(job.draw_time, 3),
                    "worst_acceleration_ratio": round(job.meta.get("worst_acceleration_ratio", 0.0), 6),
                    "worst_velocity_ratio": round(job.meta.get("worst_velocity_ratio", 0.0), 6),
                    "tracer_made": job.meta.get("tracer_made"), "mesh": job.meta.get("mesh")})
        job_part = self._totals[1]
        return {"file": self.name, "machine": self.machine.name, **job_part,
                "tracer": self.tracer, "tracer_options": self.tracer_options,
                "can_undo": bool(self.undo_stack), "can_redo": bool(self.redo_stack),
                "job": self.job_id, "version": self.version, "planning": self.planning}

    def view(self, flat: bool = False) -> dict:
        """Everything the page draws: the work area, each stroke as executed (positions
        at the sample instants and the speed there), its control points, the travels.

        ``flat``: the geometry as a few flat arrays (``geometry``, ``travels`` as 5 numbers each) instead
        of an object per stroke and a pair per point: what the page asks for (docs/studio.md). While a
        large drawing is planned in the background, the flat view is its traced paths (``preview``)."""
        with self.lock:
            m = self.machine
            out = {"machine": {"name": m.name, "width": m.width, "height": m.height, "margin": m.margin,
                               "home": list(m.home), "vmax": max(m.x.max_velocity, m.y.max_velocity),
                               "delta_time": m.delta_time, "pen_up_delay": m.pen.up_delay,
                               "pen_down_delay": m.pen.down_delay}}
            if self.job is None and self.preview is not None and flat:
                offsets, xy = thin_paths(self.preview.polylines)
                self._previewed.set()
                return {**out, "strokes": [], "travels": [], "layers": [], "summary": self.summary(),
                        "preview": {"offsets": offsets, "xy": np.round(xy, 2).ravel().tolist()}}
            job = self._require()
            out.update(summary=self.summary(), layers=self._view_layers(job))
            if not flat:
                strokes = [self._view_stroke(n, st, sa) for n, (st, sa) in enumerate(zip(job.strokes, job.samples))]
                return {**out, "strokes": strokes, "travels": self._view_travels(job)}
            return {**out, "geometry": self._view_geometry(job),
                    "travels": np.ravel(self._view_travels(job, lists=False)).tolist()}

    def _view_geometry(self, job: Job) -> dict:
        """Every stroke's view in flat arrays: ``offsets`` (n + 1) into ``xy`` (x, y pairs) and ``speed``;
        ``control_offsets`` into ``control``; per stroke ``degree``, ``length``, ``time`` and ``layer``
        (an index into ``layer_names``)."""
        arrays = [self._stroke_arrays(st, sa, len(job.strokes)) for st, sa in zip(job.strokes, job.samples)]
        names = list(job.layers)
        index = {n: k for k, n in enumerate(names)}
        return {"degree": [st.spline.degree for st in job.strokes],
                "length": np.round([st.spline.length for st in job.strokes], 3).tolist(),
                "time": np.round([len(sa.velocity) * sa.delta_time for sa in job.samples], 4).tolist(),
                "layer": [index[st.layer] for st in job.strokes], "layer_names": names,
                "offsets": _offsets([a[0] for a in arrays]),
                "xy": np.concatenate([a[0] for a in arrays]).ravel().tolist(),
                "speed": np.concatenate([a[1] for a in arrays]).tolist(),
                "control_offsets": _offsets([a[2] for a in arrays]),
                "control": np.concatenate([a[2] for a in arrays]).ravel().tolist()}

    def _view_layers(self, job: Job) -> list[dict]:
        """The layers panel: each layer in plotting order with its pen (number, name, colour) and size."""
        pens, m = job.layer_pens, self.machine
        out = []
        for name in job.layers:
            k = pens[name]
            pen = m.pens[k - 1] if 0 < k <= len(m.pens) else None
            mine = [st for st in job.strokes if st.layer == name]
            out.append({"name": name, "pen": k, "pen_name": m.describe_pen(k, f"pen {k}"),
                        "colour": (pen.colour if pen is not None and pen.colour
                                   else job.meta.get("layer_colours", {}).get(name, "")),
                        "strokes": len(mine), "length_mm": round(sum(st.spline.length for st in mine), 1)})
        return out

    def _view_stroke(self, n: int, st: Stroke, sa) -> dict:
        """One stroke of the view: executed positions every sample instant (mm), the speed there (mm/s),
        control points."""
        pos, speed, control = self._stroke_arrays(st, sa)
        return {"i": n, "degree": st.spline.degree, "length": round(st.spline.length, 3), "control": control.tolist(),
                "points": pos.tolist(), "speed": speed.tolist(), "time": round(len(sa.velocity) * sa.delta_time, 4),
                "layer": st.layer}

    def _stroke_arrays(self, st: Stroke, sa, strokes: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(positions, speeds, control points) of a stroke as the view rounds them; cached per stroke
        (an edit re-plans one, the others are drawn as they were)."""
        hit = self._views.get(id(st))
        if hit is None or hit[0] is not st or hit[1] is not sa:
            speed = np.concatenate([[0.0], np.hypot(*sa.velocity.T)])
            hit = self._views[id(st)] = (st, sa, (np.round(sa.integrate(), 3), np.round(speed, 2),
                                                  np.round(st.spline.control, 4)))
            if len(self._views) > max(20000, 3 * strokes):  # strokes of old jobs and old edits: start again
                self._views = {id(st): hit}
        return hit[2]

    @staticmethod
    def _view_travels(job: Job, lists: bool = True):
        """[x0, y0, x1, y1, duration] per travel (mm, s), rounded as the strokes are (an array: lists=False)."""
        if not job.travels:
            return [] if lists else np.zeros((0, 5))
        a = np.array([[*t.start, *t.end, t.duration] for t in job.travels], float)
        a[:, :4], a[:, 4] = np.round(a[:, :4], 3), np.round(a[:, 4], 4)
        return a.tolist() if lists else a

    def patch(self) -> dict:
        """What the last edit changed, for a page that has the view: the re-planned strokes' entries,
        the travels next to them ([index, row] each), the summary, and the figures of the first of them (one answer instead of
        /api/view and /api/stroke: a fraction of the bytes, one request)."""
        with self.lock:
            job = self._require()
            if not self.last_changed:
                raise InputError("the last edit changed the strokes' order or number; fetch the whole view")
            # only the travels into and out of the changed strokes: a generated drawing has 10^4 of them
            near = sorted({k for n in self.last_changed for k in (n, n + 1)})
            rows = self._view_travels(replace(job, travels=tuple(job.travels[k] for k in near)))
            return {"strokes": [self._view_stroke(n, job.strokes[n], job.samples[n]) for n in self.last_changed],
                    "travels": [[k, row] for k, row in zip(near, rows)], "summary": self.summary(),
                    "figures": self.stroke(self.last_changed[0])}

    def stroke(self, i: Any) -> dict:
        """The figures of one stroke: the report's plots (path velocity sqrt(b(u)), axis velocities and
        accelerations against their limits, the executed path's distance from the curve per period)."""
        with self.lock:
            job = self._require()
            k = self._index(i, len(job.strokes))
            st, sa = job.strokes[k], job.samples[k]
            p = st.profile
            acc, vel, dev, _ = self.checks(st, sa)
            v = np.vstack([np.zeros((1, 2)), sa.velocity])
            a = np.diff(v, axis=0) / sa.delta_time  # the PLC ramps: constant per period
            t = np.arange(len(v)) * sa.delta_time
            m = self.machine
            return {"i": k, "length_mm": round(st.spline.length, 3), "control_points": len(st.spline.control),
                    "time_s": round(len(sa.velocity) * sa.delta_time, 4), "planned_time_s": round(p.duration, 4),
                    "worst_acceleration_ratio": round(acc, 6), "worst_velocity_ratio": round(vel, 6),
                    "max_between_samples_mm": round(float(dev.max(initial=0.0)), 4),
                    "fit_error_mm": round(st.fit_error, 4),
                    "plots": {"u": p.u.tolist(), "sqrt_b": np.sqrt(np.maximum(p.b, 0.0)).tolist(),
                              "t": t.tolist(), "vx": v[:, 0].tolist(), "vy": v[:, 1].tolist(),
                              "ta": t[:-1].tolist(), "ax": a[:, 0].tolist(), "ay": a[:, 1].tolist(),
                              "vmax": [m.x.max_velocity, m.y.max_velocity],
                              "amax": [m.x.max_acceleration, m.y.max_acceleration],
                              "deviation": dev.tolist(), "path_tolerance": m.path_tolerance}}

    def timeline(self, layers: Any = None) -> dict:
        """The executed motion for the simulation: times (s) and pen positions (mm), pen state.
        Strokes as the PLC integrates their velocity samples; travels by their law; pen delays as waits.
        ``layers``: the motion of those layers only (what 'plot one layer' sends: the live view follows it)."""
        from doodlecam.plan.travel import travel_state

        with self.lock:
            job = self._require()
            if layers is not None:
                job = self.only_layers(job, layers)
            m = self.machine
            ts, xs, pen = [0.0], [np.asarray(m.home, float)], [0]
            now = 0.0

            def add(times, pts, down):
                nonlocal now
                ts.extend((now + times).tolist())
                xs.extend(pts)
                pen.extend([down] * len(times))
                now += float(times[-1])

            lifts = job.lifts + (True,)  # the pen stays down between strokes that meet (Job.lifts)
            pens = [m.pen_number(n) for n in job.pen_numbers]  # each pen's own delays ([[pen]])
            for k, tr in enumerate(job.travels):
                if tr.duration > 0 and lifts[min(k, len(job.strokes))]:
                    tt = np.linspace(0.0, tr.duration, max(2, int(tr.duration / 0.02) + 1))
                    add(tt, travel_state(tr, m, tt)[0], 0)
                if k == len(job.strokes):
                    break
                sa = job.samples[k]
                if lifts[k]:
                    add(np.array([pens[k].down_delay]), [xs[-1]], 0)
                pos = sa.integrate()
                add(np.arange(len(pos)) * sa.delta_time, pos, 1)
                if lifts[k + 1]:
                    add(np.array([pens[k].up_delay]), [xs[-1]], 0)
            return {"t": np.round(ts, 5).tolist(), "xy": np.round(np.array(xs), 3).tolist(), "pen": pen,
                    "duration": now}

    # ------------------------------------------------------------ export, save, load

    def export(self, post: str, layers: Any = None) -> tuple[str, bytes]:
        """(file name, bytes) of one post of the current job (of ``layers`` only, when given)."""
        (_, ext, data), = self.posts((post,), layers)
        return Path(self.name).stem + ext, data

    def posts(self, names: tuple[str, ...], layers: Any = None) -> list[tuple[str, str, bytes]]:
        """[(post, extension, bytes)] of the current job, as ``pipeline.run_posts``."""
        with self.lock:
            job = self._require()
            if layers is not None:
                job = self.only_layers(job, layers)
            for post in names:
                registry.get("postprocessor", post, self.settings.plugin_dirs)  # unknown post: one line
            return run_posts(job, replace(self.settings, posts=tuple(names)))

    def save(self) -> dict:
        """The edited job as versioned JSON: the machine and every stroke's spline, in drawing order."""
        with self.lock:
            job = self._require()
            return {"format": JOB_FORMAT, "version": JOB_VERSION, "machine": self.machine.name, "source": self.name,
                    "strokes": [{"degree": s.spline.degree, "control": s.spline.control.tolist(),
                                 "source_index": s.source_index, "fit_error": s.fit_error} for s in job.strokes]}

    def open_job(self, data: bytes, name: str = "job.json") -> dict:
        """Load a saved job and plan it (no tracing)."""
        strokes, source = read_job(data, name, self.machine.name, self.machine)
        drawing = replace(_curves(strokes), source=source)
        job = plan_job(drawing, self.machine, self.settings.solver or self.machine.solver, self.settings.plugin_dirs,
                       smoothing=self.settings.smoothing, fitted=strokes)
        with self.lock:
            self.name, self.data = source or name, b""
            self._generation += 1  # a drawing still being planned in the background is dropped
            self._checks.clear()
            self._worst_of = None
            self._views.clear()
            self._set(job, keep_history=False, preview=None, planning=None)
            self._check_later(job)
            return self.summary()


def refit(spline: Spline, tolerance: float) -> Spline:
    """The stroke's curve fitted again by the fitter, within ``tolerance`` mm of the curve as it is:
    a traced zig-zag of hundreds of control points becomes a few handles. The curve is sampled densely
    enough (every 0.05 mm, at least 20 samples per control point) that the fit sees its corners."""
    from doodlecam.geometry.fit import fit_polyline

    n = int(np.clip(max(spline.length / 0.05, 20 * len(spline.control)), 200, 200_000))
    pts = spline(np.linspace(0.0, 1.0, n))
    fitted, _ = fit_polyline(pts, spline.degree, tolerance, max_control=len(spline.control))
    return fitted if len(fitted.control) < len(spline.control) else spline


PREVIEW_STEP = 1.0  # mm between the points of the traced paths shown while planning; with PREVIEW_TURN the
# thinned paths stay within 0.05 mm of the traced ones (5 000 generated paths: 1.03 M points -> 95 k)
PREVIEW_TURN = np.radians(15.0)  # and a point every this much turning (corners, tight curves)


def thin_paths(paths, step: float = PREVIEW_STEP) -> tuple[list[int], np.ndarray]:
    """(offsets, points) of the polylines ``paths`` (mm) thinned for drawing: each keeps its ends and a
    point every ``step`` mm of its length and every PREVIEW_TURN of its turning. All paths at once (no Python per point):
    a generated drawing's SVG flattens to 10^6 points, the preview needs a tenth of them."""
    counts = np.array([len(p) for p in paths])
    xy = np.concatenate(paths)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    seg = np.diff(xy, axis=0)
    d = np.concatenate([[0.0], np.hypot(seg[:, 0], seg[:, 1])])
    d[first] = 0.0  # no length from one path to the next
    s = np.cumsum(d)
    s -= np.repeat(s[first], counts)  # arc length from each path's start
    keep = np.zeros(len(xy), bool)
    bins = np.floor(s / step)
    keep[1:] = bins[1:] != bins[:-1]
    # and a point every PREVIEW_TURN of turning, so a tight curve keeps its shape (within ~step * turn / 4)
    heading = np.arctan2(seg[:, 1], seg[:, 0])
    turn = np.concatenate([[0.0], np.abs((np.diff(heading) + np.pi) % (2 * np.pi) - np.pi), [0.0]])
    c = np.cumsum(turn)
    c -= np.repeat(c[first], counts)  # from each path's start (the turn onto it from the previous one drops out)
    bins = np.floor(c / PREVIEW_TURN)
    keep[1:] |= bins[1:] != bins[:-1]
    last = first + counts - 1
    keep[first] = keep[last] = True
    starts = np.cumsum(keep)[first] - 1  # index of each path's first kept point
    return np.append(starts, keep.sum()).astype(int).tolist(), xy[keep]


def _offsets(arrays) -> list[int]:
    """Where each of ``arrays`` starts in their concatenation, and the total: n + 1 numbers."""
    return np.concatenate([[0], np.cumsum([len(a) for a in arrays])]).astype(int).tolist()


def _curves(strokes: list[Stroke]) -> Drawing:
    """The strokes' curves, densely sampled: what plan_job checks for reachability
    (the curve, not its control points, which may lie outside a non-convex workspace)."""
    return Drawing(tuple(st.spline(np.linspace(0.0, 1.0, 16 * len(st.spline.control))) for st in strokes), units="mm")


# a saved job is an input like any other: what the fitter makes, nothing that costs more than it could
DEGREES = range(2, 6)  # as the profiles' [fit] degree
MAX_STROKE_CONTROL = 200_000  # control points in one stroke (a long continuous line)
MAX_JOB_CONTROL = 2_000_000  # control points in the whole job


def spline_problem(degree: int, control: np.ndarray, profile=None) -> str | None:
    """What makes a curve one the studio must not plan, or None: a supported degree, degree + 1 to
    MAX_STROKE_CONTROL finite [x, y] points, none farther than one work area from it (a clamped B-spline lies
    in the hull of its control points; the planner then checks the curve itself against the work area).
    One rule for edits and saved jobs, checked before any work."""
    c = np.asarray(control, float)
    if degree not in DEGREES:
        return f"degree {degree!r}; the studio plans degrees 2 to 5"
    if c.ndim != 2 or c.shape[1] != 2:
        return "control points must be [x, y] pairs in mm"
    if not np.isfinite(c).all():
        return "control points must be finite"
    if not degree + 1 <= len(c) <= MAX_STROKE_CONTROL:
        return f"{len(c)} control points; a degree-{degree} stroke takes {degree + 1} to {MAX_STROKE_CONTROL}"
    if profile is not None:
        w, h = profile.width, profile.height
        out = np.maximum.reduce([-w - c[:, 0], -h - c[:, 1], c[:, 0] - 2 * w, c[:, 1] - 2 * h])
        if out.max() > 0:
            x, y = c[np.argmax(out)]
            return (f"control point ({x:.1f}, {y:.1f}) mm is far outside the {w:g} x {h:g} mm work area "
                    f"of '{profile.name}'; keep it on the paper")
    return None


def check_spline(spline: Spline, profile, what: str) -> None:
    """An edited curve, checked as saved jobs are (``spline_problem``): one-line InputError."""
    why = spline_problem(spline.degree, spline.control, profile)
    if why is not None:
        raise InputError(f"{what}: {why}")


def read_job(data: bytes, name: str, machine: str | None = None, profile=None) -> tuple[list[Stroke], str]:
    """Strokes and source name of a saved studio job (format version 1); one-line InputErrors, all checked
    before any work: the degree one the fitter makes, finite points near the work area, sizes capped."""
    try:
        doc = json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"{name}: not a JSON file ({e}); give a job saved by the studio") from None
    if not isinstance(doc, dict) or doc.get("format") != JOB_FORMAT:
        raise InputError(f"{name}: not a doodlecam studio job (no \"format\": \"{JOB_FORMAT}\"); give a job saved by the studio")
    if doc.get("version") != JOB_VERSION:
        raise InputError(f"{name}: job format version {doc.get('version')!r}; this doodlecam reads version {JOB_VERSION}")
    if machine is not None and doc.get("machine") != machine:
        raise InputError(f"{name}: saved for machine '{doc.get('machine')}', the studio runs '{machine}'; "
                         f"start it with --machine {doc.get('machine')}")
    if not isinstance(doc.get("strokes"), list):
        raise InputError(f"{name}: no list of strokes; give a job saved by the studio")
    strokes, total = [], 0
    try:
        for s in doc["strokes"]:
            degree = s["degree"]
            if not isinstance(degree, int) or isinstance(degree, bool):  # (3.0 or True would pass the range)
                raise ValueError(f"degree {degree!r}; the studio plans degrees 2 to 5")
            control = s["control"]
            if not isinstance(control, list) or len(control) > MAX_STROKE_CONTROL:
                raise ValueError(f"more than {MAX_STROKE_CONTROL} control points" if isinstance(control, list)
                                 else "no list of control points")
            total += len(control)
            if total > MAX_JOB_CONTROL:
                raise ValueError(f"the job has more than {MAX_JOB_CONTROL} control points")
            pts = np.asarray(control, float)
            why = spline_problem(degree, pts, profile)  # (a point farther than one work area off: not this machine's)
            if why is not None:
                raise ValueError(why)
            strokes.append(Stroke(Spline(degree, pts), source_index=int(s.get("source_index", -1)),
                                  fit_error=float(s.get("fit_error", 0.0))))
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"{name}: stroke {len(strokes)} is malformed ({e}); give a job saved by the studio") from None
    if not strokes:
        raise InputError(f"{name}: the job has no strokes")
    return strokes, str(doc.get("source", ""))
