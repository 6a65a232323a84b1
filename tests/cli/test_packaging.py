"""The example files and the systemd unit ship with the package; `init-config` writes them out.

The wheel test builds the wheel (`pip wheel . --no-deps`) and checks its file list: the robot
files, the example path and the unit are inside, so a `pip install` outside the repository has
them. `init-config` is run from this environment.
"""

from __future__ import annotations

import configparser
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from controller.cli import configs as config_cmd
from controller.cli import exitcodes, main

REPO = Path(__file__).resolve().parents[2]
SHIPPED = sorted(
    p.name for p in (REPO / "config").iterdir() if p.suffix in (".toml", ".csv", ".service")
)


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_wheel_holds_the_examples_and_the_unit(tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(REPO), "--no-deps", "-q", "-w", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=170,
        check=False,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    (wheel,) = tmp_path.glob("cablebot-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    pkg = config_cmd.EXAMPLES_PACKAGE
    assert {"desk.toml", "paper-acre.toml", "square-path.csv", "cablebot@.service"} <= set(SHIPPED)
    assert {"cia402-desk.toml", "cia402-sim.toml"} <= set(SHIPPED)
    for name in SHIPPED:
        assert f"{pkg}/{name}" in names, sorted(names)
        with zipfile.ZipFile(wheel) as z:
            assert z.read(f"{pkg}/{name}") == (REPO / "config" / name).read_bytes()
    assert "controller/cli/configs.py" in names and "controller/cli/monitor.py" in names
    # Every package of the source tree ships (pyproject.toml lists them one by one).
    for init in sorted(
        (*(REPO / "controller").rglob("__init__.py"), *(REPO / "drivers").rglob("__init__.py"))
    ):
        assert init.relative_to(REPO).as_posix() in names, init.parent.relative_to(REPO)


def test_the_examples_are_found_through_the_package() -> None:
    assert config_cmd.list_examples() == SHIPPED
    assert config_cmd.find_example("desk") == config_cmd.examples_dir() / "desk.toml"
    with pytest.raises(
        FileNotFoundError,
        match=re.escape(
            "there are: cablebot@.service, cia402-desk.toml, cia402-sim.toml, "
            "circle-stretch.toml, desk"
        ),
    ):
        config_cmd.find_example("nope")


def test_init_config_writes_an_example(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    desk = (REPO / "config" / "desk.toml").read_bytes()
    assert run(capsys, "init-config", "--example", "desk")[:2] == (0, "wrote desk.toml\n")
    assert (tmp_path / "desk.toml").read_bytes() == desk
    code, _, err = run(capsys, "init-config", "--example", "desk")
    assert code == exitcodes.REFUSED and "desk.toml exists; --force to overwrite it" in err
    (tmp_path / "desk.toml").write_text("mine")
    assert run(capsys, "init-config", "--example", "desk", "--force")[0] == 0
    assert (tmp_path / "desk.toml").read_bytes() == desk
    assert run(capsys, "init-config", "--example", "paper-acre", "robot.toml")[0] == 0
    assert (tmp_path / "robot.toml").read_bytes() == (
        REPO / "config" / "paper-acre.toml"
    ).read_bytes()
    (tmp_path / "etc").mkdir()
    assert run(capsys, "init-config", "--example", "cablebot@.service", "etc")[0] == 0
    assert (tmp_path / "etc" / "cablebot@.service").is_file()
    code, out, _ = run(capsys, "init-config", "--example", "square-path.csv", "-")
    assert code == 0 and out == (REPO / "config" / "square-path.csv").read_text()
    code, out, err = run(capsys, "init-config", "--example", "nope")
    assert code == exitcodes.REFUSED and "no example 'nope'; there are:" in err
    code, out, err = run(capsys, "init-config")
    assert code == exitcodes.USAGE and out.split() == SHIPPED and "--example NAME" in err
    # what it writes is a valid robot file
    assert run(capsys, "check-config", "robot.toml")[0] == exitcodes.OK


def test_unit_is_a_template_without_a_hard_coded_install_path() -> None:
    unit = configparser.ConfigParser(strict=False, interpolation=None)
    unit.optionxform = str  # type: ignore[assignment,method-assign]
    unit.read(REPO / "config" / "cablebot@.service")
    svc = unit["Service"]
    assert svc["ExecStart"] == "/usr/bin/env cablebot run --config %E/cablebot/%i.toml"
    assert svc["Type"] == "notify" and svc["WatchdogSec"] == "2s"
    assert svc["RestartPreventExitStatus"] == str(exitcodes.USAGE)  # a configuration error
    for key, value in (*unit["Unit"].items(), *svc.items()):
        assert "/opt/" not in value and ".venv" not in value, (key, value)
    guide = (REPO / "docs" / "hardware.md").read_text()
    assert "systemctl enable --now cablebot@desk" in guide


def test_unit_passes_systemd_analyze_verify(tmp_path: Path) -> None:
    tool = shutil.which("systemd-analyze")
    if tool is None:
        pytest.skip("systemd-analyze is not installed")
    instance = tmp_path / "cablebot@desk.service"
    instance.write_bytes((REPO / "config" / "cablebot@.service").read_bytes())
    proc = subprocess.run(
        [tool, "verify", str(instance)], capture_output=True, text=True, timeout=60, check=False
    )
    problems = [line for line in proc.stderr.splitlines() if str(instance) in line]
    assert proc.returncode == 0 and problems == [], proc.stderr
