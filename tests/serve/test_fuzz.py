"""Fuzzing the request parser: any input line gets exactly one JSON reply with ok or a documented error code."""

from __future__ import annotations

import json

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from robocal.serve.bundle import load_bundle  # noqa: E402
from robocal.serve.protocol import ERROR_CODES, Service  # noqa: E402

_SVC: dict = {}


def _service(path):
    if path not in _SVC:
        from conftest import LOADERS

        _SVC[path] = Service(load_bundle(path, loaders=LOADERS))
    return _SVC[path]


json_leaf = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**20), 10**20),
    st.floats(allow_nan=False, allow_infinity=False),
    st.text(max_size=8),
)
json_value = st.recursive(
    json_leaf, lambda c: st.lists(c, max_size=8) | st.dictionaries(st.text(max_size=8), c, max_size=6), max_leaves=30
)
numbers = st.one_of(st.floats(-400, 400), st.integers(-400, 400))
target = st.one_of(
    st.fixed_dictionaries({"q_deg": st.lists(numbers, min_size=0, max_size=8)}),
    st.fixed_dictionaries(
        {
            "xyz_mm": st.lists(numbers, max_size=4),
            "quat_wxyz": st.lists(st.floats(-1, 1), max_size=5),
            "q_seed_deg": st.lists(numbers, max_size=7),
        }
    ),
    json_value,
)
request = st.fixed_dictionaries(
    {},
    optional={
        "op": st.sampled_from(["correct", "info", "ping", "stats", "x", ""]) | json_leaf,
        "id": json_leaf,
        "targets": st.lists(target, max_size=4) | json_value,
        "temperatures": st.dictionaries(
            st.sampled_from([f"T_j{i}_C" for i in range(1, 7)] + ["T_l1_C", "T_l4_C", "T_l5_C", "x"]),
            numbers | json_leaf,
        )
        | st.lists(numbers, max_size=10)
        | json_value,
        "payload_kg": numbers | json_leaf,
        "mode": st.sampled_from(["pose", "position", "x"]) | json_leaf,
        "tool": st.sampled_from(["T1", "T2"]) | json_leaf,
    },
)


def _check(reply: bytes) -> None:
    assert reply.endswith(b"\n") and reply.count(b"\n") == 1
    r = json.loads(reply)
    if r["ok"]:
        return
    assert r["error"]["code"] in ERROR_CODES and r["error"]["code"] != "internal", r
    assert isinstance(r["error"]["message"], str) and r["error"]["message"]


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(req=request)
def test_structured_requests(full_bundle, req):
    _check(_service(full_bundle).handle_line(json.dumps(req).encode()))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(raw=st.binary(max_size=200) | st.text(max_size=200).map(str.encode))
def test_raw_bytes(full_bundle, raw):
    _check(_service(full_bundle).handle_line(raw))
