"""Plugin discovery reads the installed distributions once, and each distribution's metadata once."""

from importlib.metadata import Distribution, distribution

import pytest

from doodlecam import registry


@pytest.fixture
def fresh_scan():
    registry._all_entry_points.cache_clear()
    yield
    registry._all_entry_points.cache_clear()


def test_entry_points_name_their_distribution_parsed_once_each(fresh_scan, monkeypatch):
    parsed = []
    metadata = Distribution.metadata

    def counted(self):
        parsed.append(self)
        return metadata.fget(self)

    monkeypatch.setattr(Distribution, "metadata", property(counted))
    infos = registry.discover()
    ours = [i for i in infos if i.origin.startswith("entry point")]
    assert {(i.kind, i.name) for i in ours} >= {("tracer", "vector"), ("postprocessor", "gcode"),
                                                ("machine", "cartesian")}
    monkeypatch.undo()
    dist = distribution("doodlecam")
    assert {i.origin for i in ours} == {f"entry point, {dist.name} {dist.version}"}
    assert len(parsed) == 1  # 20-odd entry points of one distribution: its METADATA parsed once, not twice each
