"""The configuration reference, `docs/configuration.md`, written from the schema.

`python -m controller.service.config.reference` prints it; `--write` writes it into
`docs/configuration.md` of the repository (`make docs`), `--check` exits 1 when the file there
differs. Every row comes from `controller.service.config.schema.SECTIONS` (the key, its default
and description) and `drivers.registry.FAMILIES` (the `[drive]` options); the unit is read from
the key's name.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from controller.service.config.schema import SECTIONS, Key, Section
from drivers import registry

DOC_PATH = Path(__file__).resolve().parents[3] / "docs" / "configuration.md"
"""Where `--write` puts the reference (the repository's `docs/configuration.md`)."""

_UNIT_SYMBOLS = (
    ("_m_per_rev2", "m/turn²"),
    ("_per_rps", "units/(motor turn/s)"),
    ("_per_rev", "units/motor turn"),
    ("_mps2", "m/s²"),
    ("_rps2", "rev/s²"),
    ("_mps", "m/s"),
    ("_rps", "rev/s"),
    ("_hz", "Hz"),
    ("_nm", "N m"),
    ("_kg", "kg"),
    ("_rev", "rev"),
    ("_n", "N"),
    ("_m", "m"),
    ("_s", "s"),
    ("_a", "A"),
)
"""The unit a key's name ends with, as the reference writes it (longest suffixes first)."""

INTRO = """\
One TOML file per robot (UTF-8), validated at start-up: unknown keys (with a did-you-mean
hint), wrong types, values written with units ("2 m/s"), out-of-range values (every number
finite and within ±1e9), duplicate node ids, singular anchor layouts, an unknown
`bus.interface`, a `[bus.options]` key the interface's python-can bus class does not take, a
Zenoh endpoint without a valid port and a Zenoh `config_file` that does not load are errors
naming the file and the key (`desk.toml: reels[2].metres_per_rev: must be > 0, got -0.1`), all
of them in one run, one line each. Units are part of the key names. Check a file without
starting anything with `cablebot check-config FILE`.

`cablebot run` without `--config` uses the built-in robot (`default`): the paper's
80.9 m x 50 m x 7.62 m robot on four simulated reels, power-up pose (0, 0, 2) m, nothing
persisted. Its simulated drives share the machine's CPU with everything else, so it allows a
reading 0.5 s and a heartbeat 1 s of age and a tracking error of 1 m before it faults, and its
simulated drives idle after 1 s without a command (a real rig keeps 50 ms, 0.5 s, about 0.25 m
and a 0.3 s drive watchdog).

Shipped, all with the package (`cablebot init-config --example NAME`):

* `config/paper-acre.toml`: the paper robot against `cablebot sim` over udp_multicast (Zenoh
  prefix `cablebot/paper-acre`);
* `config/desk.toml`: a 1 m tabletop rig, ODrives on can0, 500 Hz;
* `config/cia402-desk.toml`: the same rig on CiA 402 servo drives, nodes 1..4 on can0, 500 Hz;
* `config/cia402-sim.toml`: that rig on simulated CiA 402 drives (`cablebot sim` and
  `cablebot run` over host-only udp_multicast);
* `config/circle-stretch.toml`: the paper robot with elastic cables (the simulator's physical
  plant, EA 2e5 N) and the controller's stretch model, for `cablebot demo circle` or
  `cablebot sim` + `cablebot run` ([cable stretch](cable-stretch.md));
* `config/cablebot@.service`: a systemd `Type=notify` template unit (see
  [systemd](hardware.md#systemd)).
"""

UDP_NOTE = """\
## udp_multicast stays on this host

python-can's udp_multicast sends with a multicast TTL of 1 by default, which puts every CAN
frame on the local network. cablebot opens every udp_multicast bus (daemon, `cablebot sim`,
bench, demo, tests) with `hop_limit = 0`: frames reach the other processes on this host and
never leave it. Two simulated robots on one host are kept apart by their **port**
(`[bus.options] port`): python-can binds the port on every address, so two buses on one port
hear each other whatever their groups. Setting `hop_limit` yourself (≥ 1) makes a deliberate
bus across hosts: **every frame then goes onto your network**, to every host that joined the
group, unauthenticated: use it only on a network that belongs to the robot.
"""


def unit_of(name: str) -> str:
    """The unit a key's name ends with ("m/s" for `max_speed_mps`), "–" for none. Raises
    nothing."""
    for suffix, symbol in _UNIT_SYMBOLS:
        if name.endswith(suffix):
            return symbol
    return "–"


def _value(v: Any) -> str:
    if v is None:
        return "unset"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'`"{v}"`'
    if isinstance(v, float):
        return f"{v:g}".replace("e+0", "e").replace("e+", "e")
    if isinstance(v, tuple | list):
        return f"`{json.dumps(list(v))}`"
    return str(v)


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _key_row(k: Key) -> str:
    unit = k.unit if k.unit is not None else unit_of(k.name)
    default = k.shown if k.shown is not None else _value(k.default)
    return f"| `{k.name}` | {unit} | {_cell(default)} | {_cell(k.description)} |"


def _range(o: registry.Option) -> str:
    lo = f"> {o.gt:g}" if o.gt is not None else f"≥ {o.ge:g}" if o.ge is not None else ""
    hi = f"≤ {o.le:g}" if o.le is not None else ""
    return ", ".join(p for p in (lo, hi) if p)


def _option_row(family: registry.Family, o: registry.Option) -> str:
    default = "required" if o.required else _value(o.default)
    unit = "path" if o.kind == "path" else unit_of(o.name)
    rng = _range(o)
    text = f"{family.title}: {o.doc}" + (f" ({rng})" if rng else "")
    if o.kind == "path":
        text += "; `~` expanded; the file must exist"
    return f"| `{o.name}` | {unit} | {_cell(default)} | {_cell(text)} |"


def _heading(s: Section) -> str:
    if not s.name:
        return "## Top level"
    return f"## `[[{s.name}]]`" if s.name == "reels" else f"## `[{s.name}]`"


def render() -> str:
    """The whole reference as Markdown (deterministic: the same schema gives the same text).
    Raises nothing."""
    out = [
        "# Configuration reference",
        "",
        "<!-- Written by `python -m controller.service.config.reference --write` (`make docs`)",
        "     from `controller/service/config/schema.py` and `drivers/registry.py`;",
        "     edit those, not this file. -->",
        "",
        INTRO,
        "Sections: "
        + ", ".join(f"[{_heading(s)[3:]}](#{_anchor(_heading(s)[3:])})" for s in SECTIONS)
        + ".",
        "",
    ]
    for s in SECTIONS:
        out += [_heading(s), ""]
        if s.note:
            out += [s.note[0].upper() + s.note[1:] + ".", ""]
        out += ["| key | unit | default | meaning |", "|---|---|---|---|"]
        out += [_key_row(k) for k in s.keys]
        if s.name == "drive":
            for family in registry.FAMILIES.values():
                out += [_option_row(family, o) for o in family.options]
        out.append("")
    out.append(UDP_NOTE)
    return "\n".join(out)


def _anchor(heading: str) -> str:
    """The GitHub anchor of a heading's text (lower case, punctuation dropped, spaces to -)."""
    text = heading.strip().lower()
    kept = "".join(c for c in text if c.isalnum() or c in " -_")
    return kept.replace(" ", "-")


def main(argv: Sequence[str] | None = None) -> int:
    """Print the reference, write it (`--write`) or compare it (`--check`, exit 1 when the
    committed file differs). Raises OSError if the file cannot be read or written."""
    ap = argparse.ArgumentParser(
        prog="python -m controller.service.config.reference",
        description="Write the configuration reference (docs/configuration.md) from the schema.",
    )
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--write", action="store_true", help=f"write {DOC_PATH}")
    mode.add_argument("--check", action="store_true", help=f"exit 1 if {DOC_PATH} differs")
    args = ap.parse_args(argv)
    text = render()
    if args.write:
        DOC_PATH.write_text(text, encoding="utf-8")
        print(f"wrote {DOC_PATH}")
        return 0
    if args.check:
        same = DOC_PATH.is_file() and DOC_PATH.read_text(encoding="utf-8") == text
        if not same:
            print(f"{DOC_PATH} is out of date: run make docs", file=sys.stderr)
        return 0 if same else 1
    sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
