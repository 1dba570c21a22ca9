import subprocess
import sys

import pytest

from emgail_jax.host.command_line import ArgumentParser


def _parser() -> ArgumentParser:
    parser = ArgumentParser(prog="tool")
    parser.add_argument("--algo", choices=("emgail", "gail"), default="emgail")
    parser.add_argument("--seeds", type=int, default=1)
    return parser


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--algo", "walker"], "argument --algo: invalid choice: 'walker'"),
        (["--seeds", "two"], "argument --seeds: invalid int value: 'two'"),
        (["--sedes", "2"], "unrecognized arguments: --sedes 2"),
    ],
)
def test_bad_input_is_one_line_and_exit_code_2(capsys, argv, message):
    with pytest.raises(SystemExit) as stopped:
        _parser().parse_args(argv)
    assert stopped.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1
    assert "(usage: tool --help)" in err


def test_help_still_prints_the_usage_whole(capsys):
    with pytest.raises(SystemExit) as stopped:
        _parser().parse_args(["--help"])
    assert stopped.value.code == 0
    assert "usage: tool" in capsys.readouterr().out


def test_the_commands_refuse_a_bad_choice_in_one_line():
    """As users type them: the parser is the one every command line builds."""
    commands = [
        ["-m", "emgail_jax.run", "--algo", "walker"],
        ["-m", "emgail_jax.reoptimize", "RUN", "--keep-draw", "least"],
    ]
    for command in commands:
        done = subprocess.run(
            [sys.executable, *command], capture_output=True, text=True, timeout=120
        )
        assert done.returncode == 2
        assert done.stderr.startswith("error: argument ") and done.stderr.count("\n") == 1
