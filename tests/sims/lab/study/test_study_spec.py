"""Study specs: grid order, normalization, and refusal of bad keys before any cell runs."""

from __future__ import annotations

import pytest

from decentral.errors import InputError
from sims.cli.main import main
from sims.lab.study.cells import check_cells
from sims.lab.study.engines import LocalEngine
from sims.lab.study.runner import run_study
from sims.lab.study.spec import parse_spec


def test_cells_are_the_product_of_the_grid_with_fixed_values(specs):
    """Every combination of the grid appears once, each with the fixed values, last key fastest."""
    spec = parse_spec(specs["localize"])
    cells = spec.cells()
    assert len(cells) == 4
    assert [(c["loss"], c["reference"]) for c in cells] == [(0.0, "A0"), (0.0, "nobody"), (0.3, "A0"), (0.3, "nobody")]
    assert all(c["scenario"] == "multi" and c["n_assemblies"] == 2 for c in cells)


def test_integer_given_for_a_float_option_names_the_same_cell(specs):
    """loss = 0 and loss = 0.0 normalize to the same cell key."""
    a = check_cells(parse_spec(specs["localize"].replace("loss = [0.0, 0.3]", "loss = [0, 0.3]")))
    b = check_cells(parse_spec(specs["localize"]))
    assert [c.key for c in a] == [c.key for c in b]


@pytest.mark.parametrize("kind, old, new, key", [
    ("localize", "steps = 4", "n_asemblies = 4", "n_asemblies"),
    ("localize", "seed = [1]", "sed = [1]", "sed"),
    ("ensemble", 'shape = "triple"', 'shape = "triple"\nwindow = 5', "window"),
    ("localize", 'name = "tiny-loss"', 'name = "tiny-loss"\nengine = "ray"', "engine"),
])
def test_unknown_key_exits_2_naming_the_key_and_file_before_anything_runs(write_spec, specs, tmp_path, capsys,
                                                                         kind, old, new, key):
    """A key neither the scenario nor the command knows: exit 2, one line naming it and the file, no store."""
    spec = write_spec(specs[kind].replace(old, new))
    out = tmp_path / "out"
    assert main(["study", str(spec), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and key in err and str(spec) in err
    assert not (out / "study.sqlite").exists()


@pytest.mark.parametrize("replace, field", [
    (("loss = [0.0, 0.3]", "loss = [0.0, 1.5]"), "loss"),
    (("mode = \"admm\"", "mode = \"magic\""), "mode"),
    (("loss = [0.0, 0.3]", "loss = []"), "loss"),
    (("scenario = \"multi\"", "scenario = \"nowhere\""), "scenario"),
    (("n_assemblies = 2", "n_assemblies = \"two\""), "n_assemblies"),
    (("loss = [0.0, 0.3]", "loss = [0.0, 0.0]"), "loss"),
])
def test_bad_value_is_refused_naming_the_key(specs, replace, field):
    """A value the command refuses raises InputError naming the key before any cell runs."""
    with pytest.raises(InputError, match=field):
        check_cells(parse_spec(specs["localize"].replace(*replace), "spec.toml"))


def test_ensemble_options_that_need_each_other_are_refused(specs):
    """loss without distributed, and distributed with a baseline method, are refused up front."""
    with pytest.raises(InputError, match="loss"):
        check_cells(parse_spec(specs["ensemble"] + "loss = [0.1]\n"))
    with pytest.raises(InputError, match="method"):
        check_cells(parse_spec(specs["ensemble"].replace('shape = "triple"', 'shape = "triple"\ndistributed = true\n'
                                                                         'method = "mds"')))


def test_store_with_other_keys_is_refused_with_the_difference(specs, tmp_path):
    """Re-running into a store made by a spec with other keys refuses and says which key differs."""
    run_study(parse_spec(specs["ensemble"].replace("n = [60, 120]", "n = [60]").replace("seed = [1, 2]", "seed = [1]")),
              tmp_path, LocalEngine(1))
    other = parse_spec(specs["ensemble"] + "tol = [0.01]\n")
    with pytest.raises(InputError, match="tol"):
        run_study(other, tmp_path, LocalEngine(1))


def test_dashed_key_is_refused_with_the_underscore_spelling(specs):
    """A CLI-style key (share-forms) is refused with a hint naming share_forms."""
    with pytest.raises(InputError, match="share_forms"):
        parse_spec(specs["localize"].replace("steps = 4", "steps = 4\nshare-forms = \"first\""))


def test_admm_with_the_bearing_estimator_is_refused(specs):
    """mode = "admm" runs the windowed estimator only: estimator = "bearing" beside it is refused."""
    with pytest.raises(InputError, match="estimator"):
        check_cells(parse_spec(specs["localize"].replace("steps = 4", "steps = 4\nestimator = \"bearing\"")))


def test_a_billion_cell_grid_is_refused_before_any_cell_exists(tmp_path):
    """A small spec whose grid makes 10^9 cells exits 2 with one line naming DECENTRAL_MAX_CELLS, in bounded memory."""
    from tests.sims.hostile.harness import assert_refused, run_in_process

    values = ", ".join(str(i) for i in range(10))
    grid = "\n".join(f"k{j} = [{values}]" for j in range(9))
    spec = tmp_path / "huge.toml"
    spec.write_text(f'name = "huge"\ncommand = "ensemble"\n[fixed]\nshape = "triple"\n[grid]\n{grid}\n')
    outcome = run_in_process(["study", spec, "-o", tmp_path / "out"], tmp_path)
    assert_refused(outcome, "DECENTRAL_MAX_CELLS")
    assert str(spec) in outcome.lines[0] and "1000000000" in outcome.lines[0]


def test_the_cell_limit_is_raised_by_its_variable(specs, monkeypatch):
    """DECENTRAL_MAX_CELLS=3 refuses a 4-cell study; unset, the same study passes."""
    spec = parse_spec(specs["localize"], "spec.toml")
    assert len(spec.cells()) == 4
    monkeypatch.setenv("DECENTRAL_MAX_CELLS", "3")
    with pytest.raises(InputError, match="DECENTRAL_MAX_CELLS"):
        spec.cells()
