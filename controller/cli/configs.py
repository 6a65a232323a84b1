"""`cablebot check-config FILE` (or `--config FILE`) and `cablebot init-config --example NAME`.

`check-config` validates a robot file (every problem at once, as `load_config` reports them)
and prints what it means: anchors, the footprint, the workspace box, the cable lengths the
workspace needs against the allowed range, limits, loop, faults, homing, bus and Zenoh.
Exit 0 when the file is valid, 1 with the problems on stderr otherwise.

`init-config` writes one of the example files that ship with the package (the robot files,
the example path and the systemd unit, from the top-level `config/` directory) so that a
`pip install` has them too.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from controller.cli import exitcodes

EXAMPLES_PACKAGE = "cablebot_examples"
"""The package the top-level `config/` directory is installed as (see pyproject.toml)."""

Point2 = tuple[float, float]


# --------------------------------------------------------------------------------------------
# The shipped examples


def examples_dir() -> Path:
    """The directory holding the shipped example files.

    Raises FileNotFoundError when the package was installed without them.
    """
    try:
        pkg = importlib.import_module(EXAMPLES_PACKAGE)
    except ImportError:
        pkg = None
    for entry in getattr(pkg, "__path__", []):
        # An editable install adds a path-hook entry next to the real directory: skip it.
        if Path(entry).is_dir():
            return Path(entry)
    raise FileNotFoundError(f"the example files ({EXAMPLES_PACKAGE}) are not installed")


def list_examples() -> list[str]:
    """File names of the shipped examples, sorted."""
    d = examples_dir()
    return sorted(p.name for p in d.iterdir() if p.is_file() and not p.name.startswith(("_", ".")))


def find_example(name: str) -> Path:
    """The example called `name` (a file name, or a robot file's name without `.toml`).

    Raises FileNotFoundError naming the examples there are.
    """
    names = list_examples()
    for candidate in (name, f"{name}.toml"):
        if candidate in names:
            return examples_dir() / candidate
    raise FileNotFoundError(f"no example {name!r}; there are: {', '.join(names)}")


# --------------------------------------------------------------------------------------------
# What the workspace (controller.core.workspace) needs of the cables (pure)


def polygon_area_m2(poly: Sequence[Point2]) -> float:
    """Area of a simple polygon (shoelace formula)."""
    n = len(poly)
    twice = sum(
        poly[i][0] * poly[(i + 1) % n][1] - poly[(i + 1) % n][0] * poly[i][1] for i in range(n)
    )
    return abs(twice) / 2.0


def _distance_to_polygon_m(p: Point2, poly: Sequence[Point2]) -> float:
    """Plan-view distance from `p` to the convex counter-clockwise `poly` (0 inside)."""
    n = len(poly)
    inside = True
    best = math.inf
    for k in range(n):
        a, b = poly[k], poly[(k + 1) % n]
        ex, ey = b[0] - a[0], b[1] - a[1]
        if ex * (p[1] - a[1]) - ey * (p[0] - a[0]) < 0.0:
            inside = False
        den = ex * ex + ey * ey
        t = 0.0 if den == 0.0 else ((p[0] - a[0]) * ex + (p[1] - a[1]) * ey) / den
        t = max(0.0, min(1.0, t))
        best = min(best, math.hypot(p[0] - a[0] - t * ex, p[1] - a[1] - t * ey))
    return 0.0 if inside else best


def workspace_cable_range_m(
    anchors_m: Sequence[Sequence[float]], poly: Sequence[Point2], floor_z_m: float, top_z_m: float
) -> tuple[float, float]:
    """Shortest and longest cable any point of the workspace prism needs.

    The prism is `poly` (convex) between `floor_z_m` and `top_z_m`; the longest cable is at
    one of its corners, the shortest at the point of the prism nearest an anchor.
    """
    longest = 0.0
    shortest = math.inf
    for ax, ay, az in anchors_m:
        for x, y in poly:
            for z in (floor_z_m, top_z_m):
                longest = max(longest, math.dist((ax, ay, az), (x, y, z)))
        dxy = _distance_to_polygon_m((ax, ay), poly)
        dz = az - min(max(az, floor_z_m), top_z_m)
        shortest = min(shortest, math.hypot(dxy, dz))
    return shortest, longest


def sample_workspace(cfg: Any, ws: Any, points: int = 30_000) -> dict[str, Any]:
    """The workspace's shape (`Workspace.inside_points` without the cable lengths) sampled at
    the centres of a regular grid of about `points` cells over its box: its volume, the
    shortest and longest cable it needs, and (with a payload) the fraction of it where the
    cables hold the payload by the tension rule (limits and margin); `points_m` is the (M, 3)
    array of the sampled points inside; where the payload is held nowhere, `closest` is the
    point where the tensions come closest to the rule, and the rule's reason there. Raises
    nothing for a valid configuration."""
    import numpy as np

    ranges = ws.box()
    box = math.prod(hi - lo for lo, hi in ranges)
    step = (box / points) ** (1.0 / 3.0)
    counts = [max(1, round((hi - lo) / step)) for lo, hi in ranges]
    axes = [
        lo + (np.arange(k) + 0.5) * (hi - lo) / k
        for (lo, hi), k in zip(ranges, counts, strict=True)
    ]
    cell = math.prod((hi - lo) / k for (lo, hi), k in zip(ranges, counts, strict=True))
    grid = np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=1)
    kept = grid[ws.inside_points(grid, lengths=False)]
    anchors = np.asarray(cfg.anchors_m, dtype=np.float64)
    lengths = np.sqrt(((kept[:, None, :] - anchors[None]) ** 2).sum(axis=2))
    out: dict[str, Any] = {
        "step_m": step,
        "points": int(kept.shape[0]),
        "points_m": kept,
        "volume_m3": kept.shape[0] * cell,
        "cable_range_m": [float(lengths.min()), float(lengths.max())] if kept.size else None,
    }
    if cfg.payload is not None and cfg.tension is not None and kept.size:
        from controller.service.config import tension_check

        chk = tension_check(cfg.payload, cfg.tension, cfg.geometry)
        _, margin, _, limiting = chk.statics.solve_batch(kept, chk.mass_kg)
        held = (limiting >= 0) & (margin >= chk.margin_n)
        out["held_fraction"] = float(held.mean())
        if not held.any():  # why: the rule's reason where the tensions come closest
            best = kept[int(np.where(limiting >= 0, margin, -np.inf).argmax())]
            out["closest"] = (tuple(float(v) for v in best), chk.check(best))
    return out


# --------------------------------------------------------------------------------------------
# Describing a configuration


def _volume(v: float) -> str:
    return f"{v:,.0f}" if v >= 100.0 else f"{v:.4g}"


def _range(lo: float, hi: float) -> str:
    return f"{lo:+.3f}..{hi:+.3f} m"


def _workspace_lines(
    cfg: Any, ws: Any, anchors: Sequence[Sequence[float]], work: Sequence[Point2]
) -> tuple[list[str], tuple[float, float], dict[str, Any], Any]:
    """check-config's `workspace` and `volume` lines, the cable range the workspace needs, the
    JSON of the workspace and the sampled points inside it. Raises ValueError when the cables
    hold the payload nowhere."""
    lim = cfg.limits
    top_z = ws.top_z_m
    lines: list[str] = []
    (x_lo, x_hi), (y_lo, y_hi), _ = ws.box()
    sampled = sample_workspace(cfg, ws)
    radius = "" if ws.print_radius_m is None else f", within {ws.print_radius_m:g} m of the origin"
    if ws.hanging:
        lo, hi = workspace_cable_range_m(anchors, work, lim.floor_z_m, top_z)
        lines.append(
            f"workspace  x {_range(x_lo, x_hi)}, y {_range(y_lo, y_hi)},"
            f" z {_range(lim.floor_z_m, top_z)} (footprint shrunk by {lim.xy_margin_m:g} m,"
            f" {polygon_area_m2(work):.3f} m²{radius})"
        )
    else:
        lo, hi = sampled["cable_range_m"] or (0.0, 0.0)
        lines.append(
            f"workspace  among the anchors: their hull shrunk by {lim.xy_margin_m:g} m across"
            f" the plan view, z {_range(lim.floor_z_m, top_z)}{radius}"
            f" (x {_range(x_lo, x_hi)}, y {_range(y_lo, y_hi)}, {polygon_area_m2(work):.3f} m²"
            " seen from above)"
        )
    held = sampled.get("held_fraction")
    volume = (
        f"volume     {_volume(sampled['volume_m3'])} m³ (sampled on a"
        f" {sampled['step_m'] * 1e3:.0f} mm grid)"
    )
    if held is not None and cfg.payload is not None:
        volume += (
            f"; the {cfg.payload.mass_kg:g} kg payload is held within the tension limits in"
            f" {held * 100.0:.1f} % of it"
        )
        if held == 0.0:
            at, why = sampled["closest"]
            raise ValueError(
                f"{cfg.source}: the cables cannot hold the {cfg.payload.mass_kg:g} kg payload "
                "anywhere in the workspace within the tension limits (limits.min_tension_n.."
                f"max_tension_n, tension_margin_n): where they come closest, at ({_xyz(at)}) m, "
                f"{why}"
            )
    lines.append(volume)
    data = {
        "polygon_m": [list(p) for p in work],
        "x_m": [x_lo, x_hi],
        "y_m": [y_lo, y_hi],
        "z_m": [lim.floor_z_m, top_z],
        "among_anchors": not ws.hanging,
        "volume_m3": sampled["volume_m3"],
        "held_fraction": held,
    }
    return lines, (lo, hi), data, sampled["points_m"]


def describe(cfg: Any) -> tuple[list[str], list[str], dict[str, Any]]:
    """What a valid RobotConfig means: (lines to print, notes, the same as JSON-ready data).

    Notes are not errors: e.g. parts of the workspace that need cables outside the allowed
    range (moves there will be refused).
    """
    from controller.core.workspace import Workspace

    lim = cfg.limits
    ws = Workspace.from_limits(lim, cfg.geometry)  # raises WorkspaceError for no workspace
    top_z = ws.top_z_m
    anchors = [tuple(float(v) for v in a) for a in cfg.anchors_m]
    footprint = list(ws.footprint_m)
    work = list(ws.polygon_m)  # never empty: Workspace refuses a margin that leaves nothing
    lines = [f"robot      {cfg.name!r} from {cfg.source}"]
    lines.append(f"anchors    {len(anchors)} cables (in cable order)")
    for i, r in enumerate(cfg.reels):
        m = r.reel
        x, y, z = anchors[i]
        lines.append(
            f"  cable {i + 1}  node {r.node_id:2d}  anchor ({x:+.3f}, {y:+.3f}, {z:+.3f}) m"
            f"  {m.metres_per_rev * 1e3:.2f} mm/drum turn, gear {m.gear_ratio:g},"
            f" direction {m.direction:+d}, advantage {m.mechanical_advantage:g}"
        )
    fx = [p[0] for p in footprint]
    fy = [p[1] for p in footprint]
    lines.append(
        f"footprint  x {_range(min(fx), max(fx))}, y {_range(min(fy), max(fy))},"
        f" {polygon_area_m2(footprint):.3f} m² (the anchors' plan view)"
    )
    notes: list[str] = []
    data: dict[str, Any] = {
        "name": cfg.name,
        "source": cfg.source,
        "anchors_m": [list(a) for a in anchors],
        "node_ids": list(cfg.node_ids),
        "footprint_m": [list(p) for p in footprint],
    }
    ws_lines, (lo, hi), ws_data, inside_m = _workspace_lines(cfg, ws, anchors, work)
    lines.append(ws_lines[0])
    lines.append(
        f"cables     allowed {lim.min_cable_m:.3f}..{lim.max_cable_m:.3f} m;"
        f" the workspace needs {lo:.3f}..{hi:.3f} m"
    )
    too_long = ws.lengths_violation([hi])
    if too_long is not None and too_long.limit == "max_cable_m":
        notes.append(
            f"parts of the workspace need cables up to {hi:.3f} m, longer than max_cable_m"
            f" ({lim.max_cable_m:g} m): moves there will be refused"
        )
    too_short = ws.lengths_violation([lo])
    if too_short is not None and too_short.limit == "min_cable_m":
        notes.append(
            f"parts of the workspace need cables down to {lo:.3f} m, shorter than"
            f" min_cable_m ({lim.min_cable_m:g} m): moves there will be refused"
        )
    lines.append(ws_lines[1])
    data["workspace"] = {**ws_data, "cable_range_m": [lo, hi]}
    lines.append(
        f"limits     speed {lim.max_speed_mps:g} m/s (default {lim.default_speed_mps:g}),"
        f" accel {lim.max_accel_mps2:g} m/s², cable speed {lim.max_cable_speed_mps:g} m/s"
    )
    ten = cfg.tension
    if cfg.payload is not None and ten is not None:
        lines.append(
            f"statics    payload {cfg.payload.mass_kg:g} kg, cable tensions"
            f" {ten.min_n:g}..{ten.max_n:.4g} N (maximum from {ten.max_source}),"
            f" commands {ten.margin_n:g} N inside"
        )
    else:
        lines.append("statics    no [payload]: cable tensions are not checked")
    (x_lo, x_hi), (y_lo, y_hi), _ = ws.box()
    stretch = _stretch_lines(
        cfg, ws, ((x_lo + x_hi) / 2.0, (y_lo + y_hi) / 2.0), lim.floor_z_m, top_z, inside_m
    )
    if stretch is not None:
        lines.append(stretch[0])
        data["stretch"] = stretch[1]
    from controller.cli.sag_report import sag_lines, sag_poses

    centre = ((x_lo + x_hi) / 2.0, (y_lo + y_hi) / 2.0)
    sagged = sag_lines(cfg, sag_poses(cfg, centre, (x_hi, y_hi), lim.floor_z_m, top_z))
    if sagged is not None:
        lines.extend(sagged[0])
        data["sag"] = sagged[1]
    from controller.cli.modes_cmd import modes_lines

    mode_text, mode_data = modes_lines(cfg)
    lines.extend(mode_text)
    data.update(mode_data)
    lp = cfg.loop
    pub_hz = lp.rate_hz / max(1, lp.publish_every)
    lines.append(
        f"loop       {lp.rate_hz:g} Hz, pose published at {pub_hz:g} Hz,"
        f" {'real-time (SCHED_FIFO ' + str(lp.rt_priority) + ')' if lp.realtime else 'normal'}"
        f" scheduling, auto-arm {'when simulated' if lp.auto_arm is None else lp.auto_arm}"
    )
    f = cfg.faults
    lines.append(
        f"faults     stale encoder {f.stale_timeout_s:g} s, heartbeat {f.heartbeat_timeout_s:g} s,"
        f" residual {f.residual_max_m * 1e3:g} mm, tracking {f.tracking_max_m * 1e3:g} mm,"
        f" arming {f.arm_timeout_s:g} s, bus errors {f.bus_error_timeout_s:g} s"
    )
    h = cfg.homing
    pu = h.power_up_position_m
    lines.append(
        "homing     "
        + ("no power-up pose (run `cablebot home X Y Z`)" if pu is None else f"power-up {pu} m")
        + (f", offsets saved to {h.state_file}" if h.state_file else ", offsets not saved")
    )
    if cfg.payload is not None:
        lines.append(
            f"pretension `home --pretension`: at most {h.pretension_speed_mps:g} m/s of cable, "
            f"still below {h.pretension_still_mps * 1e3:g} mm/s for {h.pretension_settle_s:g} s, "
            f"at most {h.pretension_max_travel_m:g} m per cable in {h.pretension_timeout_s:g} s"
        )
    b = cfg.bus
    opts = "".join(f", {k}={v}" for k, v in b.options.items())
    rate = "" if b.bitrate is None else f", {b.bitrate} bit/s"
    from drivers import registry

    fam = registry.family(cfg.drive.kind)
    drive_opts = ", ".join(f"{k} = {_toml_text(v)}" for k, v in cfg.drive.options.items())
    lines.append(
        f"drive      {fam.title}s ({cfg.drive.kind})" + (f": {drive_opts}" if drive_opts else "")
    )
    sim = f", simulated {fam.title}s in the daemon" if cfg.sim.enabled else ""
    lines.append(f"bus        {b.interface} {b.channel}{rate}{opts}{sim}")
    from drivers import busload

    load = busload.for_config(cfg.drive, len(cfg.reels), cfg.loop, cfg.bus)
    lines.append(f"bus load   {load.describe()}")
    data["bus_load"] = load.as_dict()
    if load.enforced and load.percent > 80.0:
        notes.append(
            f"the bus load is {load.percent:.0f} % (worst case {load.worst_percent:.0f} %): "
            "little headroom, frames wait for each other and readings arrive late; a lower "
            "loop rate or a second bus gives room"
        )
    zc = cfg.zenoh
    lines.append(
        f"zenoh      {zc.mode}, listen {', '.join(zc.listen) or 'nowhere'}"
        + (f", connect {', '.join(zc.connect)}" if zc.connect else "")
        + f", prefix {zc.prefix}"
        + (f", config {zc.config_file}" if zc.config_file else "")
    )
    data["config"] = cfg.summary()
    return lines, notes, data


def _stretch_lines(
    cfg: Any, ws: Any, centre_xy: Point2, floor_z: float, top_z: float, inside_m: Any
) -> tuple[str, list[dict[str, Any]]] | None:
    """The check-config line on cable stretch (None: rigid cables) and its JSON: the most any
    cable stretches under the planned tensions at the power-up pose and at the workspace's
    centre line, at the floor, half-way and the top (``docs/cable-stretch.md``). Where the
    centre line leaves the workspace (the narrow top of the anchors' pyramid) the nearest of
    the sampled points inside it (`inside_m`, (M, 3)) stands in. Raises nothing."""
    eas = [r.cable_ea_n for r in cfg.reels]
    if all(e is None for e in eas) or cfg.payload is None or cfg.tension is None:
        return None
    from controller.core.stretch import CableStretch
    from controller.service.config import tension_check

    model = CableStretch(cfg.geometry, eas, tension_check(cfg.payload, cfg.tension, cfg.geometry))
    known = sorted({e for e in eas if e is not None})
    ea_text = (
        "/".join(f"{e:g}" for e in known) + " N" + (" (some reels rigid)" if None in eas else "")
    )
    cx, cy = centre_xy
    poses: list[tuple[str, tuple[float, float, float]]] = []
    pu = cfg.homing.power_up_position_m
    if pu is not None:
        poses.append(("power-up", (float(pu[0]), float(pu[1]), float(pu[2]))))
    for name, z in (("floor", floor_z), ("middle", (floor_z + top_z) / 2.0), ("top", top_z)):
        p = (cx, cy, z)
        if ws.check_point(p) is not None and len(inside_m):
            q = inside_m[int(((inside_m - p) ** 2).sum(axis=1).argmin())]
            p = (float(q[0]), float(q[1]), float(q[2]))
        poses.append((name, p))
    parts = []
    out: list[dict[str, Any]] = []
    for name, p in poses:
        try:
            paid, tensions = model.ipk(p)
        except ValueError as exc:  # KinematicsError: no tensions there
            parts.append(f"{name} ({_xyz(p)}): {exc}")
            continue
        geo = model.stretched_m(paid, tensions)
        st = [g - q for g, q in zip(geo, paid, strict=True)]
        parts.append(f"{max(st) * 1e3:.1f} mm at {name} ({_xyz(p)})")
        out.append({"pose": name, "position_m": list(p), "stretch_m": st})
    line = (
        f"stretch    cable EA {ea_text}, pose from {cfg.loop.stretch_tensions} tensions; "
        f"most stretch: {', '.join(parts)}"
    )
    return line, out


def _xyz(p: Sequence[float]) -> str:
    """A pose to a tenth of a millimetre (no -0, no 1e-16)."""
    return ", ".join(f"{round(v, 4) + 0.0:g}" for v in p)


def _toml_text(v: Any) -> str:
    """A scalar as a robot file writes it (true, 0.1, 131072, a path)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return format(v, "g")
    return str(v)


def invalid_report(file: str, exc: BaseException) -> dict[str, Any]:
    """`check-config --json` for a file that is not valid: `{"ok": false, "file", "errors":
    [{"key", "problem", "message"}, ...]}`, one entry per problem found."""
    from controller.service.config import ConfigError

    if isinstance(exc, ConfigError):
        errors = [{"key": e.key, "problem": e.problem, "message": str(e)} for e in exc.errors]
    else:
        errors = [{"key": "", "problem": str(exc), "message": str(exc)}]
    return {"ok": False, "file": file, "errors": errors}


def cmd_check_config(args: argparse.Namespace) -> int:
    """`cablebot check-config FILE` (or `--config FILE`, as every other verb names its robot
    file): validate and describe; exit 1 with every problem (with `--json` also as a JSON
    object on stdout, see `invalid_report`), 2 without a file or with two different ones."""
    from controller.service.config import ConfigError, load_config

    if args.file is not None and args.config is not None and args.file != args.config:
        print(
            f"cablebot check-config: two files, {args.file} and --config {args.config}: name one",
            file=sys.stderr,
        )
        return exitcodes.USAGE
    args.file = args.file if args.file is not None else args.config
    if args.file is None:
        print("cablebot check-config: name the robot file: check-config FILE", file=sys.stderr)
        return exitcodes.USAGE
    try:
        cfg = load_config(args.file)
        lines, notes, data = describe(cfg)
    except (ConfigError, ValueError, OSError) as exc:
        if args.json:
            print(json.dumps(invalid_report(args.file, exc), indent=2))
        print(f"{exc}", file=sys.stderr)
        print(f"cablebot: {args.file}: not a valid robot configuration", file=sys.stderr)
        return exitcodes.REFUSED
    if args.json:
        print(json.dumps({**data, "notes": notes}, indent=2))
        return exitcodes.OK
    for line in lines:
        print(line)
    for note in notes:
        print(f"note: {note}")
    print(f"ok: {args.file} is valid")
    return exitcodes.OK


def cmd_init_config(args: argparse.Namespace) -> int:
    """`cablebot init-config --example NAME [OUT]`: write a shipped example file."""
    try:
        if args.list or args.example is None:
            names = list_examples()
            print("\n".join(names))
            if args.example is None and not args.list:
                print("cablebot: init-config: name one with --example NAME", file=sys.stderr)
                return exitcodes.USAGE
            return exitcodes.OK
        src = find_example(args.example)
    except FileNotFoundError as exc:
        print(f"cablebot: {exc}", file=sys.stderr)
        return exitcodes.REFUSED
    text = src.read_text()
    if args.out == "-":
        sys.stdout.write(text)
        return exitcodes.OK
    out = Path(args.out) if args.out else Path(src.name)
    if out.is_dir():
        out = out / src.name
    if out.exists() and not args.force:
        print(f"cablebot: {out} exists; --force to overwrite it", file=sys.stderr)
        return exitcodes.REFUSED
    try:
        out.write_text(text)
    except OSError as exc:
        print(f"cablebot: cannot write {out}: {exc.strerror or exc}", file=sys.stderr)
        return exitcodes.REFUSED
    print(f"wrote {out}")
    return exitcodes.OK


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `check-config` and `init-config`."""
    p = sub.add_parser(
        "check-config",
        help="validate a robot file and print what it means (exit 1 on problems)",
    )
    p.add_argument("file", nargs="?", default=None, metavar="FILE", help="robot TOML file")
    p.add_argument(
        "--config", default=None, metavar="FILE", help="the robot TOML file (instead of FILE)"
    )
    p.add_argument("--json", action="store_true", help="print the description as JSON")
    p.set_defaults(func=cmd_check_config)

    p = sub.add_parser(
        "init-config",
        help="write an example file that ships with cablebot (robot TOML, path, systemd unit)",
    )
    p.add_argument(
        "--example", metavar="NAME", default=None, help="e.g. desk, paper-acre, cablebot@.service"
    )
    p.add_argument(
        "out",
        nargs="?",
        default=None,
        metavar="OUT",
        help="file or directory to write (default: the example's name here; - for stdout)",
    )
    p.add_argument("--force", action="store_true", help="overwrite OUT if it exists")
    p.add_argument("--list", action="store_true", help="list the examples")
    p.set_defaults(func=cmd_init_config)
