"""Hypothesis-generated malformed logs, ensembles and detections: each run either succeeds with a valid
output or is refused with exit 2 and one stderr line naming the file, writing nothing."""

from __future__ import annotations

import copy
import json
import math

import numpy as np
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from decentral.errors import InputError
from sims.io.detections_json import read_detections
from tests.sims.hostile.harness import assert_refused, run_in_process, write_json_text, write_npz

SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

#: values that break a field when put in place of another
HOSTILE = st.one_of(
    st.sampled_from([1e308, -1e308, 1e-308, 0, -1, 2**63, 10**30, True, None, "10", "", [], {}, [[[]]],
                     float("nan"), float("inf")]).map(copy.deepcopy),  # fresh containers, never shared
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(),
    st.text(max_size=5),
)


def _leaves(doc, path=()):
    """Every (path, value) of a JSON document, containers included."""
    yield path, doc
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _leaves(v, path + (k,))
    elif isinstance(doc, list):
        for k, v in enumerate(doc):
            yield from _leaves(v, path + (k,))


@st.composite
def mutated(draw, doc):
    """``doc`` with 1-3 places replaced by hostile values, deleted, or renamed (a JSON-ready copy)."""
    doc = json.loads(json.dumps(doc))
    for _ in range(draw(st.integers(1, 3))):
        paths = [p for p, _ in _leaves(doc) if p]
        if not paths:  # an earlier mutation replaced the whole content
            break
        path = draw(st.sampled_from(paths))
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        action = draw(st.sampled_from(["replace", "delete", "rename"]))
        if action == "replace" or isinstance(parent, list):
            parent[path[-1]] = draw(HOSTILE)
        elif action == "delete":
            del parent[path[-1]]
        else:
            parent[draw(st.text(min_size=1, max_size=4))] = parent.pop(path[-1])
    return doc


def _text_mutation(draw, text: str) -> str:
    """``text`` with a range deleted, repeated, or replaced by JSON punctuation."""
    a = draw(st.integers(0, len(text)))
    b = draw(st.integers(a, min(len(text), a + 40)))
    filler = draw(st.sampled_from(["", "[", "]", "{", "}", ",", '"', ":", "1" * 40, "NaN", text[a:b] * 2]))
    return text[:a] + filler + text[b:]


def _check(outcome, output, name):
    """Success writes a valid, finite output; failure is a clean refusal naming ``name``."""
    event(f"exit status {outcome.status}")
    if outcome.status == 0:  # stderr may hold the closing summary line, never an error
        assert output.exists() and "error" not in outcome.stderr and "Traceback" not in outcome.stderr
        if output.suffix == ".json":
            json.loads(output.read_text(), parse_constant=lambda c: (_ for _ in ()).throw(AssertionError(c)))
    else:
        assert_refused(outcome, name)


@SETTINGS
@given(data=st.data())
def test_mutated_logs_are_localized_or_refused(log_doc, tmp_path_factory, data):
    """A log with fields replaced, deleted or renamed: a valid estimate or a one-line refusal."""
    tmp = tmp_path_factory.mktemp("log")
    doc = data.draw(mutated(log_doc))
    log = tmp / "log.json"
    log.write_text(json.dumps(doc), encoding="utf-8")  # NaN/Infinity as the tokens Python writes
    out = tmp / "est.json"
    _check(run_in_process(["localize", log, "-o", out], tmp, trace_memory=False), out, "log.json")


@SETTINGS
@given(data=st.data())
def test_mutated_log_text_is_localized_or_refused(log_doc, tmp_path_factory, data):
    """A log whose text is cut, repeated or spliced with JSON punctuation: valid estimate or one-line refusal."""
    tmp = tmp_path_factory.mktemp("text")
    log = write_json_text(tmp / "log.json", _text_mutation(data.draw, json.dumps(log_doc)))
    out = tmp / "est.json"
    _check(run_in_process(["localize", log, "-o", out], tmp, trace_memory=False), out, "log.json")


ARRAY_CHANGES = st.sampled_from(["dtype", "shape", "extreme", "drop", "scalar", "text"])


@SETTINGS
@given(data=st.data())
def test_mutated_ensembles_are_localized_or_refused(ensemble_arrays, tmp_path_factory, data):
    """An ensemble whose arrays change dtype, shape, values or go missing: an estimate or a one-line refusal."""
    tmp = tmp_path_factory.mktemp("ens")
    arrays = dict(ensemble_arrays)
    for _ in range(data.draw(st.integers(1, 2))):
        key = data.draw(st.sampled_from(sorted(arrays)))
        change = data.draw(ARRAY_CHANGES)
        a = np.asarray(arrays[key])
        if change == "dtype":
            dtype = data.draw(st.sampled_from(["<f2", "<f8", "<i1", "<u8", "?", "<U3"]))
            with np.errstate(all="ignore"):
                arrays[key] = a.astype(dtype) if a.dtype.kind in "biuf" or dtype == "<U3" else a
        elif change == "shape":
            arrays[key] = np.resize(a, data.draw(st.sampled_from([(0,), (3,), (2, 2), (a.size + 1,), (1, 1, 1)])))
        elif change == "extreme" and a.size and a.dtype.kind in "iuf":
            b = a.astype(float if a.dtype.kind == "f" else np.int64).copy()
            b.flat[data.draw(st.integers(0, b.size - 1))] = data.draw(
                st.sampled_from([1e308, -1, 2**62, np.nan, np.inf, 0, 5e-324]) if b.dtype.kind == "f"
                else st.sampled_from([-1, 2**62, 0, 10**9]))
            arrays[key] = b
        elif change == "drop":
            arrays.pop(key)
        elif change == "scalar":
            arrays[key] = np.asarray(data.draw(st.sampled_from([0, -5, 10**15, 1.5, "x"])))
        else:
            arrays[key] = np.asarray(data.draw(st.text(max_size=4)))
        if not arrays:
            break
    obs = write_npz(tmp / "obs.npz", **arrays)
    out = tmp / "est.npz"
    outcome = run_in_process(["ensemble", obs, "-o", out], tmp, trace_memory=False)
    _check(outcome, out, "obs.npz")
    if outcome.status == 0:
        with np.load(out, allow_pickle=False) as est:
            assert np.all(np.isfinite(est["position"])) and np.all(np.isfinite(est["orientation"]))


DETECTIONS = {"format": "decentral.detections/1", "frames": [
    {"source": "f0.png", "detections": [
        {"u": 10.0, "v": 20.0, "r": 5.0, "score": 0.9, "id": 5, "track": 1,
         "tag": {"id": 5, "hamming": 0, "margin": 40.0, "corners": [[1, 2], [3, 2], [3, 4], [1, 4]]}},
        {"u": 30.0, "v": 20.0, "r": 6.0, "score": 0.8, "id": None, "track": None}]}]}


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_mutated_detections_are_read_or_refused_naming_the_file(tmp_path_factory, data):
    """A detections file with fields mutated or its text spliced: read with finite values, or InputError naming it."""
    tmp = tmp_path_factory.mktemp("dets")
    if data.draw(st.booleans()):
        text = json.dumps(data.draw(mutated(DETECTIONS)))
    else:
        text = _text_mutation(data.draw, json.dumps(DETECTIONS))
    path = write_json_text(tmp / "dets.json", text)
    try:
        frames = read_detections(path)
    except InputError as err:
        assert "dets.json" in str(err) and "\n" not in str(err)
        return
    for frame in frames:
        for d in frame.detections:
            assert all(math.isfinite(x) for x in (d.u, d.v, d.r, d.score)) and d.r > 0
            assert d.node is None or isinstance(d.node, int)
