"""`decentral study`'s own reporting: failed cells on stderr."""


def test_failed_cells_are_reported_one_line_each_on_stderr(capsys):
    """The CLI prints each failed cell's grid values and error in one warning line, then stops after ten."""
    from sims.cli.study import _FailureLines
    from sims.lab.study.cells import Cell

    lines = _FailureLines(("loss",))
    for k in range(12):
        lines(Cell("localize", {"scenario": "multi", "loss": k / 10}, str(k)), {"error": f"Boom: {k}"})
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 11 and "loss=0.0" in err[0] and "Boom: 0" in err[0] and "scenario" not in err[0]
    assert "error' column" in err[-1]
