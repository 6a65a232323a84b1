"""`cablebot import-rrf`: a robot file from a RepRapFirmware Hangprinter config.g, on stdout or
in a file, what was not mapped on stderr, nothing written on a fatal error, never a traceback;
the file it writes passes `check-config`."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from controller.cli import exitcodes, main
from controller.cli.import_rrf import MAX_INPUT_BYTES
from controller.service.config.schema import LimitsConfig
from tests.core.test_rrf import FIVE, HP4

REPO = Path(__file__).resolve().parents[2]
HP4_FILE = REPO / "tests" / "data" / "hangprinter-v4-config.g"

ANY_LAYOUT = {"ceiling_z_m", "print_radius_m"} <= set(LimitsConfig.__dataclass_fields__)
"""Whether the configuration takes the any-layout `[limits]` keys the import writes (the
Hangprinter's anchors below the effector need them to pass check-config)."""
needs_any_layout = pytest.mark.skipif(
    not ANY_LAYOUT, reason="the configuration has no limits.ceiling_z_m / print_radius_m yet"
)


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_to_stdout_with_the_unmapped_lines_on_stderr(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "import-rrf", str(HP4_FILE))
    data = tomllib.loads(out)
    assert data["name"] == "hp4-lab"
    assert [r["node_id"] for r in data["reels"]] == [40, 41, 42, 43]
    assert data["reels"][3]["anchor_m"] == [0.0, 0.0, 2.29983]
    assert f"import-rrf: {HP4_FILE}: a Hangprinter with 4 anchors (A B C D)" in err
    assert "import-rrf: not mapped (25; the robot file lists them too):" in err
    assert f"  {HP4_FILE}:6 G21: G-code units" in err
    assert f"  {HP4_FILE}:50 M204 P2000 T4000: print and travel accelerations" in err
    assert "import-rrf: wrote the robot file to stdout: robot 'hp4-lab', 4 reels" in err
    assert "Traceback" not in err
    if ANY_LAYOUT:
        assert code == exitcodes.OK, err
        assert err.rstrip().endswith("import-rrf: <stdout> passes check-config")
    else:  # the written file names the any-layout keys this configuration does not know yet
        assert code == exitcodes.REFUSED
        assert "<stdout>: limits.ceiling_z_m: unknown key" in err
        assert "the robot file was written but does not pass check-config: edit it" in err


def test_to_a_file_never_over_one_without_force(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    out = tmp_path / "hp4.toml"
    run(capsys, "import-rrf", str(HP4_FILE), "-o", str(out), "--name", "bench")
    text = out.read_text()
    assert tomllib.loads(text)["name"] == "bench"
    out.write_text("mine")
    code, stdout, err = run(capsys, "import-rrf", str(HP4_FILE), "-o", str(out))
    assert code == exitcodes.REFUSED and out.read_text() == "mine" and stdout == ""
    assert f"cablebot: import-rrf: {out} exists; --force to overwrite it (nothing written)" in err
    run(capsys, "import-rrf", str(HP4_FILE), "-o", str(out), "--force", "--name", "bench")
    assert out.read_text() == text
    assert [p.name for p in tmp_path.iterdir()] == ["hp4.toml"]  # no temporary file left


def test_an_override_file_is_read_after_config_g(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    override = tmp_path / "config-override.g"
    override.write_text("; written by M500\nM669 K6 D0:0:2350.5\nM666 Q0.1\n")
    _, out, err = run(capsys, "import-rrf", str(HP4_FILE), str(override))
    data = tomllib.loads(out)
    assert data["reels"][3]["anchor_m"] == [0.0, 0.0, 2.3505]
    assert data["reels"][0]["spool_buildup_factor_m"] == 0.0001
    assert "# anchor D\n[[reels]]" in out and f"({override}:2)" in out
    assert f"{HP4_FILE}, {override}: a Hangprinter" in err


@pytest.mark.parametrize(
    ("text", "shown"),
    [
        ("M669 K5\n", "config.g:1: M669 K5: not a Hangprinter (K6)"),
        (HP4.replace("M666 U2:2:2:4", "M666 U2:2:4"), "config.g:26: M666 U: 3 values"),
        (HP4.replace("-1610.98", "-1610,98"), "config.g:20: cannot read the line"),
        ("G21\nM83\n", "config.g: no M669 K6"),
    ],
)
def test_a_fatal_problem_writes_nothing(
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
    text: str,
    shown: str,
) -> None:
    src = tmp_path / "config.g"
    src.write_text(text)
    out = tmp_path / "robot.toml"
    monkeypatch.chdir(tmp_path)
    code, stdout, err = run(capsys, "import-rrf", "config.g", "-o", str(out))
    assert code == exitcodes.REFUSED
    assert not out.exists() and stdout == ""
    assert f"cablebot: import-rrf: {shown}" in err, err
    assert err.rstrip().endswith("cablebot: import-rrf: not imported, nothing written")
    code, stdout, err = run(capsys, "import-rrf", "config.g")
    assert code == exitcodes.REFUSED and stdout == ""


def test_every_bad_line_is_named_at_once(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    src = tmp_path / "config.g"
    src.write_text(
        HP4.replace("M666 L20:20:20:20", "M666 L20:20:0:20").replace("M208 Z2000.00", "M208 Zx")
    )
    code, _, err = run(capsys, "import-rrf", str(src))
    assert code == exitcodes.REFUSED
    assert f"{src}:23: M208 Z: needs a number or min:max in mm" in err
    assert f"{src}:28: M666 L20:20:0:20: every value must be whole numbers >= 1" in err


def test_files_that_are_not_a_configuration(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    binary = tmp_path / "firmware.bin"
    binary.write_bytes(b"\x7fELF\0\0\x01" * 100)
    big = tmp_path / "big.g"
    big.write_bytes(b"; x\n" * (MAX_INPUT_BYTES // 4 + 1))
    utf16 = tmp_path / "notepad.g"
    utf16.write_bytes(HP4.encode("utf-16"))
    for path, shown in (
        (tmp_path / "missing.g", "cannot read: No such file or directory"),
        (tmp_path, "cannot read: Is a directory"),
        (binary, "a binary file, not a RepRapFirmware configuration"),
        (utf16, "UTF-16 text: save it as UTF-8 (or ASCII) first"),
        (big, f"larger than {MAX_INPUT_BYTES:,} bytes: not a config.g"),
    ):
        code, out, err = run(capsys, "import-rrf", str(path))
        assert code == exitcodes.REFUSED and out == ""
        assert err == f"cablebot: import-rrf: {path}: {shown}; nothing written\n"


def test_latin1_comments_are_read_with_a_note(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    src = tmp_path / "config.g"
    src.write_bytes(HP4.replace("; highest Z", "; 2000 mm \xb0 highest Z").encode("latin-1"))
    _, out, err = run(capsys, "import-rrf", str(src))
    assert tomllib.loads(out)["limits"]["ceiling_z_m"] == 2.0
    assert f"import-rrf: note: {src}: not UTF-8 (byte 0xb0 on line 23): read as Latin-1" in err
    src.write_bytes(b"\xef\xbb\xbf" + HP4.encode())  # a byte order mark is not a command
    _, out, err = run(capsys, "import-rrf", str(src))
    assert tomllib.loads(out)["name"] == "hp4-lab" and "note" not in err


@needs_any_layout
@pytest.mark.parametrize("text", [HP4, FIVE + "M666 W1\nM208 S1 Z0\nM208 Z2500"])
def test_the_written_file_passes_check_config(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, text: str
) -> None:
    src = tmp_path / "config.g"
    src.write_text(text)
    out = tmp_path / "robot.toml"
    code, _, err = run(capsys, "import-rrf", str(src), "-o", str(out))
    assert code == exitcodes.OK, err
    code, stdout, err = run(capsys, "check-config", str(out))
    assert code == exitcodes.OK, err
    assert stdout.rstrip().endswith(f"ok: {out} is valid")


def test_as_a_user_runs_it(tmp_path: Path) -> None:
    """The installed command in a process of its own: the file, the listing, no traceback."""
    out = tmp_path / "hp4.toml"
    proc = subprocess.run(
        [sys.executable, "-m", "controller.cli", "import-rrf", str(HP4_FILE), "-o", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    assert "Traceback" not in proc.stderr
    assert proc.returncode == (exitcodes.OK if ANY_LAYOUT else exitcodes.REFUSED), proc.stderr
    assert proc.stdout == ""
    assert tomllib.loads(out.read_text())["limits"]["print_radius_m"] == 2.0
    assert f"import-rrf: wrote {out}: robot 'hp4-lab', 4 reels" in proc.stderr
