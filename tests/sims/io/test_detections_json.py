"""``decentral.detections/1``: round trip, validation by field, and log assembly."""

import json

import numpy as np
import pytest

from decentral.errors import InputError
from decentral.observations import Camera, ObservationLog, Pose, Step
from sims.io.detections_json import (
    DetectionFrame,
    DetectionRecord,
    TagRecord,
    assemble_log,
    read_detections,
    write_detections,
)

FRAMES = [
    DetectionFrame("a.png", (
        DetectionRecord(10.5, 20.25, 5.0, 0.9, 3, 1, TagRecord(3, 0, 55.0, np.array([[1, 2], [3, 2], [3, 4], [1, 4]], float))),
        DetectionRecord(40.0, 20.0, 6.0, 0.4, None, 2),
    )),
    DetectionFrame("b.png", ()),
]


def test_round_trip(tmp_path):
    """Written detections read back equal (ids, tracks, nulls and tag reads)."""
    p = tmp_path / "d.json"
    write_detections(p, FRAMES)
    back = read_detections(p)
    assert [f.source for f in back] == ["a.png", "b.png"]
    a, b = back[0].detections
    assert (a.u, a.v, a.r, a.node, a.track, a.tag.tag, a.tag.hamming) == (10.5, 20.25, 5.0, 3, 1, 3, 0)
    assert np.allclose(a.tag.corners, FRAMES[0].detections[0].tag.corners)
    assert b.node is None and b.track == 2 and b.tag is None


@pytest.mark.parametrize("mutate, field", [
    (lambda d: d.update(format="other/1"), "format"),
    (lambda d: d["frames"][0]["detections"][0].update(r=-1.0), "frames[0].detections[0].r"),
    (lambda d: d["frames"][0]["detections"][0].update(u="x"), "frames[0].detections[0].u"),
    (lambda d: d["frames"][0]["detections"][0].update(id=2.5), "frames[0].detections[0].id"),
    (lambda d: d["frames"][0].update(detections={}), "frames[0].detections"),
])
def test_bad_documents_name_file_and_field(tmp_path, mutate, field):
    """Each malformed field raises InputError naming the file and the field."""
    p = tmp_path / "d.json"
    write_detections(p, FRAMES)
    doc = json.loads(p.read_text())
    mutate(doc)
    p.write_text(json.dumps(doc))
    with pytest.raises(InputError) as err:
        read_detections(p)
    assert err.value.source == str(p) and err.value.field == field


def _template(steps=2):
    cam = Camera("A0", "cam0", np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]), Pose(np.eye(3), np.zeros(3)), Pose(np.eye(3), np.zeros(3)))
    config = {"A0": {0: np.zeros(3)}, "A1": {3: np.zeros(3)}}
    return ObservationLog(0.06, ("A0", "A1"), {"A0/cam0": cam}, tuple(Step(0.2 * k, config) for k in range(steps)))


def test_assemble_log_keeps_identified_detections_only():
    """Frame k fills step k of the camera with the detections that carry a node id."""
    log = assemble_log(_template(), {"A0/cam0": FRAMES})
    (d,) = log.steps[0].detections["A0/cam0"]
    assert (d.node, d.u, d.v, d.r) == (3, 10.5, 20.25, 5.0)
    assert log.steps[1].detections["A0/cam0"] == ()


def test_assemble_log_refuses_mismatched_counts():
    """More frames than steps, or an undeclared camera, raise InputError."""
    with pytest.raises(InputError):
        assemble_log(_template(steps=1), {"A0/cam0": FRAMES})
    with pytest.raises(InputError):
        assemble_log(_template(), {"A9/cam0": FRAMES})
