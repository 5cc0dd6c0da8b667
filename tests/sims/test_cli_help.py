"""``--help`` says what each option accepts and what it defaults to; option names are the same across commands."""

import pytest

from sims.cli.main import build_parser, main


def command_help(name: str) -> str:
    """The --help text of one command, on one line (argparse wraps at the terminal width)."""
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    return " ".join(sub.choices[name].format_help().split())


def test_perceive_lists_every_tag_family_the_identifier_knows():
    """--family's help names exactly the families of the AprilTag registry."""
    from agents.perception.apriltag import FAMILIES
    from sims.cli.perceive import TAG_FAMILIES

    assert TAG_FAMILIES == tuple(FAMILIES)
    assert f"AprilTag family: {', '.join(FAMILIES)} (default: tag36h11)" in command_help("perceive")


def test_agent_parity_default_is_the_transports():
    """`agent --parity-group` (a literal, so that the command starts without the transport) defaults to
    the datagram transport's own PARITY_GROUP and says so."""
    from protocols.datagrams import PARITY_GROUP

    assert f"(0: none; default: {PARITY_GROUP})" in command_help("agent")


@pytest.mark.parametrize("command,option,default", [
    ("localize", "--loss", "0.0"), ("localize", "--seed", "0"), ("localize", "--sigma-pixel", "1.0"),
    ("localize", "--sigma-radius", "0.5"), ("localize", "--sigma-odom-p", "0.005"),
    ("localize", "--sigma-odom-theta", "0.005"), ("ensemble", "--seed", "0"),
    ("make-ensemble", "--jitter", "0.03"), ("make-ensemble", "--threshold", "0.2"),
])
def test_options_show_their_default(command, option, default):
    """The option's help text ends with '(default: X)'."""
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    action = next(a for a in sub.choices[command]._actions if option in a.option_strings)
    assert action.help.endswith(f"(default: {default})"), action.help


def test_no_help_uses_the_old_default_spelling():
    """Every command writes defaults as '(default: X)'."""
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    for name, parser in sub.choices.items():
        text = " ".join(parser.format_help().split())
        assert "(default " not in text, name


def test_keys_takes_output_like_every_command(tmp_path, capsys):
    """keys takes -o/--output DIR like the other commands, and its help names no other spelling."""
    assert main(["keys", "A0", "A1", "--output", str(tmp_path / "k1")]) == 0
    assert (tmp_path / "k1" / "peers.json").exists()
    assert "-o DIR, --output DIR " in command_help("keys") and "--out " not in command_help("keys")
    assert "older spelling" not in command_help("keys")


@pytest.mark.parametrize("argv,option", [(["-n", "1"], "-n"), (["--jitter", "0.9"], "--jitter")])
def test_make_ensemble_errors_name_the_option(tmp_path, capsys, argv, option):
    """A bad -n or --jitter is reported under the option's name, not the library's field name."""
    assert main(["make-ensemble", "sphere", "-o", str(tmp_path / "o.npz"), *argv]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert f"error: {option}: " in line, line
    assert not (tmp_path / "o.npz").exists()


def test_make_ensemble_lists_every_shape_of_the_generator_with_its_dimension():
    """make-ensemble's SHAPES_2D and SHAPES_3D are exactly the generator's shapes, by dimension."""
    from sims.cli.make_ensemble import SHAPES_2D, SHAPES_3D
    from sims.simulation.ensembles.generator import SHAPES

    assert SHAPES_2D + SHAPES_3D == tuple(SHAPES)
    assert {SHAPES[s] for s in SHAPES_2D} == {2} and {SHAPES[s] for s in SHAPES_3D} == {3}


def test_the_choice_lists_repeated_for_a_light_help_equal_their_sources():
    """simulate's scenario names and odometry formats, and export's formats, equal the registries they repeat."""
    from sims.cli.export import FORMATS as EXPORT_FORMATS
    from sims.cli.simulate import ODOMETRY_FORMATS as SIMULATE_ODOMETRY
    from sims.cli.simulate import SCENARIO_NAMES
    from sims.io.trajectories import FORMATS
    from sims.simulation.robot_data import ODOMETRY_FORMATS
    from sims.simulation.scenarios import SCENARIOS

    assert SCENARIO_NAMES == tuple(SCENARIOS)
    assert SIMULATE_ODOMETRY == ODOMETRY_FORMATS
    assert EXPORT_FORMATS == FORMATS
