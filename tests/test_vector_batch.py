"""The vector tracer's batched reading (#29) gives the very points of the per-segment one.

Béziers of all shapes are sampled together (chord counts from a compiled pass, points from
NumPy with svgelements' arithmetic); ``_curve_points`` walks one segment through svgelements'
own ``npoint``. Both must agree to the bit, or the converts' files would change.
"""

import numpy as np
import pytest
import svgelements as se

from doodlecam.plugins.vector import VectorTracer, _bezier_points, _curve_points


def _segments(kind: str, n: int, seed: int):
    """Random Béziers of the kinds generated art has: ordinary, tiny, huge, with cusps and loops."""
    rng = np.random.default_rng(seed)
    size = {"cubic": 4, "quad": 3}[kind]
    ctrl = rng.normal(0, 20, (n, size, 2)) * rng.choice([1e-3, 1.0, 1e3], (n, 1, 1))
    ctrl[::7, -1] = ctrl[::7, 0]  # closed loops
    ctrl[::11, 1] = ctrl[::11, 0]  # a control point on its end: a cusp-like start
    ctrl[::13] = np.round(ctrl[::13])  # integral points, with zeros (-0.0 / 0.0) and straight ones
    ctrl[::17, 1:] = ctrl[::17, :1]  # a single point
    ctrl[5] = -0.0  # negative zeros everywhere
    cls = {"cubic": se.CubicBezier, "quad": se.QuadraticBezier}[kind]
    return ctrl, [cls(*(se.Point(*p) for p in c)) for c in ctrl]


@pytest.mark.parametrize("kind", ["cubic", "quad"])
@pytest.mark.parametrize("tol, corner", [(0.02, 30.0), (0.02, 0.0), (1e-4, 90.0), (5.0, 5.0)])
def test_batched_beziers_are_svgelements_points_to_the_bit(kind, tol, corner):
    ctrl, segs = _segments(kind, 120, seed=len(kind) + int(corner))
    batched = _bezier_points(ctrl, tol, corner)
    for p, seg in zip(batched, segs):
        q = _curve_points(seg, tol, corner)
        assert p.shape == q.shape and p.tobytes() == q.tobytes()


def test_a_segment_that_is_not_finite_is_left_to_svgelements():
    ctrl = np.array([[[0.0, 0.0], [1.0, 1.0], [np.inf, 0.0], [3.0, 0.0]], [[0.0, 0.0], [1.0, 2.0], [2.0, 2.0], [3.0, 0.0]]])
    out = _bezier_points(ctrl, 0.02, 30.0)
    assert out[0] is None and len(out[1]) > 2


def _svg(tmp_path, body: str):
    path = tmp_path / "d.svg"
    path.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="100mm" viewBox="0 0 100 100">'
                    + body + "</svg>")
    return path


def test_mixed_paths_read_as_svgelements_segments(tmp_path):
    """Lines, Béziers, arcs, closes and subpaths in one path, a polygon and a rectangle: each subpath
    is its segments' points end to end (svgelements' own per segment), zero-length steps dropped."""
    d = ("M10,10 L20,10 C25,10 30,15 30,20 Q30,30 20,30 Z M40,40 L40,40 L50,45 A5,5 0 0 1 60,45 "
         "Q65,50 60,55 L60,55 M70,70 L70,70")
    path = _svg(tmp_path, f'<path d="{d}" stroke="black" fill="none" transform="rotate(10 50 50)"/>'
                          '<polygon points="5,90 15,90 10,80" stroke="black"/>'
                          '<rect x="80" y="80" width="10" height="5" stroke="black" fill="none"/>')
    got = VectorTracer().trace(path, {"corner": 30.0}).polylines
    doc = se.SVG.parse(str(path), reify=True, ppi=96.0)
    mm = 100.0 / float(doc.width)
    want = []
    for shape in doc.elements():
        if not isinstance(shape, se.Shape):
            continue
        p = se.Path(shape)
        p.reify()
        for sub in p.as_subpaths():
            pts = []
            for seg in sub:
                if isinstance(seg, se.Move):
                    pts = [np.array([[seg.end.x, seg.end.y]])]
                elif isinstance(seg, (se.Line, se.Close)):
                    pts += [np.array([[seg.start.x, seg.start.y]])][:not pts] + [np.array([[seg.end.x, seg.end.y]])]
                else:
                    q = _curve_points(seg, 0.02 / mm, 30.0)
                    pts += [q[:1]][:not pts] + [q[1:]]
            poly = np.vstack(pts)
            poly = poly[np.r_[True, np.any(np.diff(poly, axis=0) != 0, axis=1)]]
            if len(poly) >= 2:
                want.append(poly * mm)
    # the drawing joins pieces that meet end to end: compare the points, not the strokes
    assert sum(map(len, got)) <= sum(map(len, want))
    got_pts = {tuple(p) for q in got for p in q}
    want_pts = {tuple(p) for q in want for p in q}
    assert got_pts == want_pts


def test_top_level_groups_named_after_the_shapes_drawn_before_them(tmp_path):
    """'group N' counts the shapes found before the group, skipping those that draw nothing,
    though their points are only computed after the whole document is walked."""
    path = _svg(tmp_path, '<path d="M1,1 L5,5" stroke="black"/>'
                          '<path d="M2,2 L2,2" stroke="black"/>'  # zero length: draws nothing
                          '<g><path d="M10,10 C20,0 30,20 40,10" stroke="black"/><path d="M3,3 L9,3" stroke="black"/></g>'
                          '<path d="M50,50 L60,60" stroke="black"/>'
                          '<g><g><path d="M70,70 L80,80" stroke="black"/></g></g>')
    d = VectorTracer().trace(path, {"layers": "group", "corner": 0.0})
    assert sorted(set(d.layers)) == ["0", "group 2", "group 5"]
