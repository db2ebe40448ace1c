"""Plugin discovery reads the installed distributions once, and each distribution's metadata once."""

import json
import subprocess
import sys
import textwrap
from importlib.metadata import distribution

# In a fresh interpreter: in the suite's own process, other tests have already looked plugins up (and a
# count taken there once read 0 in a full run, never alone), so the count is taken where nothing ran before.
_COUNT = textwrap.dedent("""
    import json
    from importlib.metadata import Distribution
    from doodlecam import registry

    parsed = []
    metadata = Distribution.metadata

    def counted(self):
        parsed.append(self)
        return metadata.fget(self)

    Distribution.metadata = property(counted)
    infos = registry.discover()
    ours = [(i.kind, i.name, i.origin) for i in infos if i.origin.startswith("entry point")]
    Distribution.metadata = metadata
    print(json.dumps({"ours": ours, "parsed": len(parsed)}))
""")


def test_entry_points_name_their_distribution_parsed_once_each():
    r = subprocess.run([sys.executable, "-c", _COUNT], capture_output=True, text=True, timeout=120, check=True)
    got = json.loads(r.stdout)
    ours = got["ours"]
    assert {(k, n) for k, n, _ in ours} >= {("tracer", "vector"), ("postprocessor", "gcode"), ("machine", "cartesian")}
    dist = distribution("doodlecam")
    assert {o for _, _, o in ours} == {f"entry point, {dist.name} {dist.version}"}
    assert got["parsed"] == 1  # 20-odd entry points of one distribution: its METADATA parsed once, not twice each
