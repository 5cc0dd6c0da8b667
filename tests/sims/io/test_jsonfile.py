"""The bounded JSON reader: exact depth pre-scan, digit and duplicate-key refusals, file-size limit."""

from __future__ import annotations

import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from decentral.errors import InputError
from sims.io.jsonfile import json_depth, load_json, loads_json
from sims.io.limits import Limits

tricky = st.text(alphabet='[]{}"\\ab\u00e9', max_size=6)
documents = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | tricky,
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(tricky, inner, max_size=3),
    max_leaves=20,
)


def _depth(value) -> int:
    if isinstance(value, (list, dict)):
        kids = value.values() if isinstance(value, dict) else value
        return 1 + max((_depth(k) for k in kids), default=0)
    return 0


@settings(max_examples=300, deadline=None)
@given(documents, st.booleans())
def test_depth_prescan_matches_the_parsed_nesting(doc, ascii_only):
    """Brackets inside strings (with escaped quotes and backslashes) never count."""
    assert json_depth(json.dumps(doc, ensure_ascii=ascii_only)) == _depth(doc)


def test_limits_apply_and_name_the_file(tmp_path):
    """Depth, digits and file size over their limits are refused naming the file and the variable."""
    small = Limits(max_json_depth=3, max_int_digits=5, max_file_mb=0.001)
    with pytest.raises(InputError, match="f.json.*DECENTRAL_MAX_JSON_DEPTH"):
        loads_json("[[[[1]]]]", "f.json", small)
    with pytest.raises(InputError, match="f.json.*DECENTRAL_MAX_INT_DIGITS"):
        loads_json("[123456]", "f.json", small)
    assert loads_json("[[[-12345, 1.5e300, 1234567.5]]]", "f.json", small) == [[[-12345, 1.5e300, 1234567.5]]]
    big = tmp_path / "big.json"
    big.write_text("[" + "0," * 1000 + "0]")
    with pytest.raises(InputError, match="big.json.*DECENTRAL_MAX_FILE_MB"):
        load_json(big, small)


def test_duplicate_keys_are_refused_at_any_depth():
    """A key given twice in any object is refused and named."""
    with pytest.raises(InputError, match="twice") as err:
        loads_json('{"a": {"5": 1, "6": 2, "5": 3}}', "f.json")
    assert err.value.field == "5" and err.value.source == "f.json"
