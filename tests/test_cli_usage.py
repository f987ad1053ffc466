"""The command line's own messages (issue 23, item 13): a setting without ``=``, a misspelt optimizer name and
the top-level help. None of these runs a calibration, so they are fast."""

from __future__ import annotations

import pytest

from robocal.cli import main
from robocal.commands.calibrate import optimizer_config
from robocal.errors import ConfigError


@pytest.mark.parametrize(
    "argv",
    [
        ["calibrate", "DATA", "--robot", "kr16_2", "--out", "OUT", "noise_mm"],  # after the options
        ["calibrate", "DATA", "noise_mm", "--robot", "kr16_2", "--out", "OUT"],  # before them
        ["discover", "DATA", "--robot", "kr16_2", "--out", "OUT", "noise_mm"],
    ],
)
def test_a_setting_without_equals_is_named_with_the_commands_usage(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    # the command's usage (not the top-level "robocal [-h] COMMAND ..."), and the word that is not a setting
    assert f"usage: robocal {argv[0]} " in err and "COMMAND" not in err, err
    assert f"robocal {argv[0]}: error: 'noise_mm' is not a setting: settings are key=value" in err, err


def test_an_unknown_option_is_reported_by_the_command(capsys):
    with pytest.raises(SystemExit):
        main(["calibrate", "DATA", "--robot", "kr16_2", "--out", "OUT", "--bogus"])
    err = capsys.readouterr().err
    assert "usage: robocal calibrate " in err and "unrecognized arguments: --bogus" in err


def test_a_misspelt_optimizer_gets_did_you_mean(tmp_path, capsys):
    with pytest.raises(
        ConfigError, match=r"^optimizer: must be one of \[.*'lm'.*\]; got 'levenberg'\. Did you mean 'lm'\?"
    ):
        optimizer_config("levenberg")
    with pytest.raises(ConfigError, match=r"got 'gauss-newton'\. Did you mean 'gn'\?"):
        optimizer_config("gauss-newton")
    with pytest.raises(ConfigError, match=r"got 'pso'$"):  # nothing close: no guess
        optimizer_config("pso")
    # through the command line: one line, exit 2
    code = main(["calibrate", str(tmp_path), "--robot", "kr16_2", "--out", str(tmp_path / "o"), "optimizer=levenberg"])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Did you mean 'lm'?" in err, err


def test_the_registry_suggests_by_class_name_too():
    from robocal.optimizers.registry import make_optimizer

    with pytest.raises(ConfigError, match=r"^optimizer\.name: .*got 'Levenberg-Marquardt'\. Did you mean 'lm'\?"):
        make_optimizer({"name": "Levenberg-Marquardt"})


def test_closest_name_keeps_case_sensitive_keys_and_maps_aliases():
    from robocal.config import closest_name, unknown_choice

    assert closest_name("T_l1_c", ["T_l1_C", "T_l2_C"]) == "T_l1_C"
    assert closest_name("whale-ish", ["lm", "gn"]) is None
    assert closest_name("levenberg", ["lm", "gn"], {"levenberg-marquardt": "lm"}) == "lm"
    # an alias of a name that is not allowed here is never suggested
    assert closest_name("levenberg", ["gn"], {"levenberg-marquardt": "lm"}) is None
    assert str(unknown_choice("x", "b", ["a"])) == "x: must be one of ['a']; got 'b'"


def test_top_level_help_has_no_rst_markup(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    assert "``" not in out and "robocal COMMAND --help" in out, out
    for command in ("calibrate", "serve", "urdf", "discover"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        assert "``" not in capsys.readouterr().out, command
