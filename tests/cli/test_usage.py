"""Usage errors a user can act on: did-you-mean for a mistyped verb, the verb's own usage for
arguments it does not take, and `--version`."""

from __future__ import annotations

import pytest

from controller.cli import exitcodes, main, version


def usage_error(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    with pytest.raises(SystemExit) as exc:
        main(list(argv))
    assert exc.value.code == exitcodes.USAGE
    out, err = capsys.readouterr()
    assert out == ""
    return err


def test_a_mistyped_verb_gets_did_you_mean(capsys: pytest.CaptureFixture[str]) -> None:
    err = usage_error(capsys, "stauts")
    assert (
        err.splitlines()[-1] == "cablebot: error: unknown command 'stauts'; did you mean 'status'?"
    )
    err = usage_error(capsys, "calibrat", "solve", "x.csv")
    assert "did you mean 'calibrate'?" in err
    err = usage_error(capsys, "qqqqqq")
    assert "unknown command 'qqqqqq'; `cablebot -h` lists them" in err


def test_extra_arguments_show_the_verbs_usage(capsys: pytest.CaptureFixture[str]) -> None:
    err = usage_error(capsys, "move", "1", "2", "3", "4")
    assert err.startswith("usage: cablebot move ")
    assert err.splitlines()[-1] == "cablebot move: error: unrecognized arguments: 4"
    err = usage_error(capsys, "calibrate", "solve", "x.csv", "--config", "c.toml", "--bogus")
    assert err.startswith("usage: cablebot calibrate solve ")
    assert err.splitlines()[-1].endswith("unrecognized arguments: --bogus")


def test_a_mistyped_option_gets_did_you_mean(capsys: pytest.CaptureFixture[str]) -> None:
    err = usage_error(capsys, "move", "1", "2", "3", "--sped", "3")
    assert err.startswith("usage: cablebot move ")
    assert err.splitlines()[-1] == (
        "cablebot move: error: unrecognized arguments: --sped 3; --sped: did you mean --speed?"
    )
    err = usage_error(capsys, "calibrate", "collect", "x.csv", "--atuo=3")
    assert err.splitlines()[-1].endswith("--atuo: did you mean --auto?")
    err = usage_error(capsys, "status", "--zzzz")
    assert err.splitlines()[-1] == "cablebot status: error: unrecognized arguments: --zzzz"


def test_a_bare_cablebot_lists_every_verb_one_line_each(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from controller.cli import build_parser

    err = usage_error(capsys)
    lines = err.splitlines()
    assert lines[0].startswith("usage: cablebot ")
    listed = [line.split()[0] for line in lines if line.startswith("  ")]
    verbs = next(a for a in build_parser()._actions if a.dest == "command")
    assert listed == list(verbs.choices)  # type: ignore[attr-defined]
    assert "  check-config  validate a robot file and print what it means" in err
    assert "  move          move in a straight line to X Y Z" in err
    assert lines[-1] == "`cablebot COMMAND -h` describes one"


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    out, _ = capsys.readouterr()
    assert out == f"cablebot {version()}\n"
    assert version()[0].isdigit()


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (("pose", "--count", "0"), "--count: must be at least 1"),
        (("pose", "--count", "-3"), "--count: must be at least 1"),
        (("status", "--timeout", "0"), "--timeout: must be a number of seconds > 0"),
        (("status", "--timeout", "nan"), "--timeout: must be a number of seconds > 0"),
        (("view", "--port", "99999"), "--port: a port is 0 (any) to 65535"),
        (("view", "--port", "-1"), "--port: a port is 0 (any) to 65535"),
    ],
)
def test_out_of_range_numbers_are_usage_errors(
    capsys: pytest.CaptureFixture[str], argv: tuple[str, ...], says: str
) -> None:
    err = usage_error(capsys, *argv)
    assert says in err.splitlines()[-1], err
