"""Classes of bad command-line input, each tested over every place it can occur.

Each test walks the parser (every sub-command, every path argument) or the registries
instead of naming one command, so a new option or registry inherits the guarantee.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from realitygap import cli
from realitygap.core.checks import PATH_OPTIONS, UnknownNameError
from realitygap.samples import sample_dir


def _session() -> Path:
    return sample_dir("optiodom_diffdrive") / "square" / "231220200029"


def _path_arguments() -> list[tuple[str, str]]:
    """(sub-command words, option string or positional dest) of every path argument."""
    found = []
    for sub in cli._subparsers(cli.build_parser()):
        words = sub.prog.split()[1:]
        if any(isinstance(a, argparse._SubParsersAction) for a in sub._actions):
            continue
        for action in sub._actions:
            if action.dest in PATH_OPTIONS:
                name = action.option_strings[-1] if action.option_strings else action.dest
                found.append((" ".join(words), name))
    return found


PATH_ARGUMENTS = _path_arguments()


def test_the_walk_finds_the_path_arguments() -> None:
    names = {f"{c} {o}" for c, o in PATH_ARGUMENTS}
    for expected in ("diagnose --report", "diagnose logs", "inspect paths", "benchmark --out"):
        assert expected in names, sorted(names)


@pytest.mark.parametrize(("command", "option"), PATH_ARGUMENTS, ids=lambda x: str(x))
def test_an_empty_path_is_refused_by_name(
    command: str, option: str, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = command.split()
    if option.startswith("-"):
        argv += [option, ""]
        argv += {"diagnose": ["x.npz"], "inspect": ["x.csv"], "calibrate umbmark": ["s"]}.get(
            command, []
        )
    else:
        argv += [""]
    with pytest.raises(SystemExit) as info:
        cli.main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "expected a path, got an empty string" in err


def test_a_quoted_home_is_expanded(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("HOME", str(tmp_path))
    args = cli.build_parser().parse_args(["inspect", "x.csv", "--json", "~/i.json"])
    assert args.json == str(tmp_path / "i.json")


@pytest.mark.parametrize(
    "argv",
    [
        ["inspect", str(_session()), "--json", "-", "-q"],
        ["calibrate", "umbmark", str(_session()), "--json", "-", "-q"],
    ],
    ids=["inspect", "calibrate"],
)
def test_json_dash_is_standard_output_and_only_json(
    argv: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    monkeypatch.chdir(tmp_path)
    assert cli.main(argv) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["written_by"].startswith("realitygap")
    assert list(tmp_path.iterdir()) == []


def test_an_output_inside_another_output_is_refused(tmp_path: Path, capsys) -> None:
    report = tmp_path / "r"
    argv = ["diagnose", str(_session()), "--report", str(report), "--json", str(report / "d.json")]
    assert cli.main([*argv, "-q"]) == 2
    err = capsys.readouterr().err
    assert "--json" in err and "lies inside the folder of --report" in err
    assert list(tmp_path.iterdir()) == []


def test_an_output_on_a_pseudo_file_system_is_refused(capsys) -> None:
    if not Path("/proc/self").is_dir():
        pytest.skip("no /proc here")
    assert cli.main(["inspect", str(_session()), "--json", "/proc/x.json", "-q"]) == 2
    assert "pseudo file system" in capsys.readouterr().err


@pytest.mark.parametrize("option", ["--params", "--firmware"])
def test_a_key_given_twice_in_key_value_options_is_refused(option: str, capsys) -> None:
    value = "wheelbase=0.23,wheelbase=0.3" if option == "--params" else "a_max=1,a_max=2"
    assert cli.main(["diagnose", str(_session()), option, value, "-q"]) == 2
    assert "is given twice" in capsys.readouterr().err


def test_an_effect_named_twice_is_refused(capsys) -> None:
    argv = ["diagnose", str(_session()), "--effects", "command_latency,command_latency", "-q"]
    assert cli.main(argv) == 2
    assert "command_latency given twice" in capsys.readouterr().err


def test_a_square_side_the_ground_truth_contradicts_is_refused(capsys) -> None:
    argv = ["calibrate", "umbmark", str(_session()), "--side-length", "1700", "-q"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert "--side-length 1700" in err and "a side" in err and "metres" in err


def test_the_same_file_twice_is_refused_by_inspect(tmp_path: Path, capsys) -> None:
    f = tmp_path / "a.csv"
    f.write_text("t,v\n0,1\n0.1,1\n0.2,1\n")
    (tmp_path / "link.csv").symlink_to(f)
    assert cli.main(["inspect", str(f), str(tmp_path / "link.csv"), "-q"]) == 2
    assert "the same data is given twice" in capsys.readouterr().err


def test_registry_names_are_refused_as_values_and_keys() -> None:
    from realitygap import experiments
    from realitygap.cards import card_for as card
    from realitygap.robots.effects import make_effect
    from realitygap.samples import sample_dir as sample

    for lookup in (
        lambda: make_effect("wheel_diamter_ratio"),
        lambda: experiments.get("diagnose-reel"),
        lambda: sample("no_such_sample"),
        lambda: card("realitygap/Moon-v0"),
    ):
        with pytest.raises(UnknownNameError) as info:
            lookup()
        assert isinstance(info.value, ValueError) and isinstance(info.value, KeyError)
        assert not str(info.value).startswith(("'", '"'))  # the message, not a quoted repr
