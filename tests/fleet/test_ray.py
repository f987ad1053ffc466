"""The Ray engine: a real local Ray instance (2 CPUs, no dashboard), the same bytes as in-process, shut down.

Costs ~10-15 s (Ray's start-up is most of it); skipped, with the reason, when Ray is not installed or cannot start.
"""

from __future__ import annotations

import pytest

from conftest import settings
from robocal.fleet.engine import ray_available
from robocal.fleet.run import run_fleet


def _tree(d):
    return {p.relative_to(d).as_posix(): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def ray_instance():
    ok, why = ray_available()
    if not ok:
        pytest.skip(f"Ray engine not tested: {why}")
    import ray

    from robocal.fleet.engine import start_ray

    try:
        start_ray(2)
    except Exception as exc:  # no room for its processes, ports refused, ...: say so, do not fail the suite
        pytest.skip(f"Ray engine not tested: a local Ray instance could not start ({type(exc).__name__}: {exc})")
    yield ray
    ray.shutdown()
    assert not ray.is_initialized()


def test_ray_matches_in_process_byte_for_byte(ray_instance, twin_fleet, tmp_path):
    assert ray_instance.cluster_resources().get("CPU") == 2
    r = run_fleet(twin_fleet, tmp_path / "ray", settings(), engine="ray", workers=2, progress=False)
    assert len(r["computed"]) == 9 and r["counts"]["accepted"] == 9
    assert ray_instance.is_initialized()  # started by the fixture: run_fleet leaves it running
    local = run_fleet(twin_fleet, tmp_path / "local", settings(), engine="local", progress=False)
    assert _tree(tmp_path / "ray") == _tree(tmp_path / "local")
    assert r["trends"]["flags"] == local["trends"]["flags"]
