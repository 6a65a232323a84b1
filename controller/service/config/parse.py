"""Validation: a parsed TOML mapping (or a file) -> a frozen `RobotConfig`, every problem at once.

The rules are listed in the package docstring (`controller.service.config`); each section's
keys and defaults are the schema's (`controller.service.config.schema`).
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import MappingProxyType
from typing import Any

from controller.core.commands import MAX_PATH_POINTS
from controller.core.kinematics import Geometry, KinematicsError, SingularGeometryError
from controller.core.motion.shaper import (
    MAX_DAMPING_RATIO,
    MAX_FREQUENCY_HZ,
    MAX_PASSES,
    MIN_FREQUENCY_HZ,
    SHAPER_TYPES,
)
from controller.core.reel import ReelModel, spool_buildup, spool_buildup_from_factor
from controller.core.scale import speed_scale_problem
from controller.core.statics import G_MPS2, TensionCheck
from controller.core.suggest import closest
from controller.core.workspace import Workspace, WorkspaceError, layout_geometry
from controller.service.config.heavy import cable_self_weight_problems
from controller.service.config.interfaces import _parse_bus, _parse_ros2, _parse_zenoh
from controller.service.config.schema import (
    _NAME_RE,
    FLOAT32_RESOLUTION_LIMIT_M,
    GCODE_DIALECTS,
    GCODE_UNITS,
    REEL_KEYS,
    SIM_PLANTS,
    STRETCH_TENSIONS,
    TOP_KEYS,
    TOP_KEYS_DOC,
    TORQUE_TELEMETRY,
    WATCHDOG_DEFAULT_PERIODS,
    WATCHDOG_MIN_PERIODS,
    ConfigError,
    DriveConfig,
    FaultConfig,
    GcodeConfig,
    HomingConfig,
    LimitsConfig,
    LoopConfig,
    PayloadConfig,
    ReelConfig,
    RobotConfig,
    ShaperConfig,
    SimConfig,
    TensionLimits,
    Vec3,
    defaults,
    key_names,
    kinematic_sim,
)
from controller.service.config.tables import _Errors, _Table, _tname, _unknown
from controller.service.config.tomltext import to_toml
from drivers import busload, registry

_REEL_KEYS = key_names(REEL_KEYS)
_REEL_DEFAULTS = defaults(REEL_KEYS)
_TOP_KEYS = TOP_KEYS
_TOP_DEFAULTS = defaults(TOP_KEYS_DOC)


def _parse_reel(t: _Table, family: registry.Family | None) -> ReelConfig | None:
    """One [[reels]] table; None (problems recorded) if it is not usable. `family`: the drive
    family whose node id range applies (None: the family is unknown, any 0..127)."""
    mark = t.errs.mark()
    t.finish(_REEL_KEYS)
    lo, hi = (0, 127) if family is None else (family.node_id_min, family.node_id_max)
    node_id = t.integer("node_id", ge=lo, le=hi)
    anchor = t.vec3("anchor_m")
    has_mpr, has_radius = t.has("metres_per_rev"), t.has("drum_radius_m")
    mpr = math.nan
    if has_mpr == has_radius:
        t.fail_here("give exactly one of metres_per_rev and drum_radius_m")
    elif has_mpr:
        mpr = t.number("metres_per_rev", gt=0.0)
    else:
        mpr = 2.0 * math.pi * t.number("drum_radius_m", gt=0.0)
    gear = t.number("gear_ratio", _REEL_DEFAULTS["gear_ratio"], gt=0.0)
    direction = t.integer("direction", _REEL_DEFAULTS["direction"])
    if direction not in (1, -1):
        t.fail("direction", f"must be 1 or -1, got {direction}")
    ma = t.number("mechanical_advantage", _REEL_DEFAULTS["mechanical_advantage"], gt=0.0)
    buildup = 0.0
    by_diameter = t.has("cable_diameter_m") or t.has("turns_per_layer")
    if t.has("spool_buildup_m_per_rev2") and by_diameter:
        t.fail_here(
            "give either spool_buildup_m_per_rev2 or cable_diameter_m/turns_per_layer, not both"
        )
    elif t.has("spool_buildup_factor_m") and (by_diameter or t.has("spool_buildup_m_per_rev2")):
        other = "cable_diameter_m/turns_per_layer" if by_diameter else "spool_buildup_m_per_rev2"
        t.fail_here(f"give either spool_buildup_factor_m or {other}, not both")
    elif by_diameter:
        d = t.number("cable_diameter_m", _REEL_DEFAULTS["cable_diameter_m"], ge=0.0)
        tpl = t.number("turns_per_layer", _REEL_DEFAULTS["turns_per_layer"], gt=0.0)
        buildup = spool_buildup(d, tpl)
    elif t.has("spool_buildup_factor_m"):
        factor_m = t.number("spool_buildup_factor_m", ge=0.0)
        if math.isfinite(factor_m):  # else the problem is recorded: the reel is not built
            buildup = spool_buildup_from_factor(factor_m)
    else:
        buildup = t.number(
            "spool_buildup_m_per_rev2", _REEL_DEFAULTS["spool_buildup_m_per_rev2"], ge=0.0
        )
    ref = t.number("reference_length_m", _REEL_DEFAULTS["reference_length_m"], ge=0.0)
    max_torque = t.number("max_torque_nm", gt=0.0) if t.has("max_torque_nm") else None
    cable_ea = t.number("cable_ea_n", gt=0.0) if t.has("cable_ea_n") else None
    cable_mass = t.number("cable_mass_kg_per_m", ge=0.0) if t.has("cable_mass_kg_per_m") else None
    if not t.errs.clean_since(mark) or node_id is None or anchor is None:
        return None
    try:
        model = ReelModel(
            metres_per_rev=mpr,
            gear_ratio=gear,
            direction=direction,
            mechanical_advantage=ma,
            spool_buildup_m_per_rev2=buildup,
            reference_length_m=ref,
        )
    except (ValueError, ArithmeticError) as exc:
        t.fail_here(f"unusable reel model: {exc}")
        return None
    return ReelConfig(
        node_id=node_id,
        anchor_m=anchor,
        reel=model,
        max_torque_nm=max_torque,
        cable_ea_n=cable_ea,
        cable_mass_kg_per_m=cable_mass,
    )


def _check_reel_range(rc: ReelConfig, i: int, lim: LimitsConfig, source: str) -> None:
    """Reel must reach [min_cable, max_cable] and keep float32 resolution over the range."""
    key = f"reels[{i}]"
    m = rc.reel
    try:
        lo = m.position_rev(lim.min_cable_m)
        hi = m.position_rev(lim.max_cable_m)
        for p in (lo, hi):
            if not math.isfinite(p) or m.length_rate_mps(p, 1.0) * m.direction <= 0.0:
                raise ValueError("metres per turn fall to zero within the cable range")
    except ValueError as exc:
        raise ConfigError(
            source,
            key,
            f"cannot cover limits.min_cable_m..max_cable_m "
            f"({lim.min_cable_m:g}..{lim.max_cable_m:g} m): {exc}",
        ) from exc
    # Relative encoders start near 0 at power-up, so motor positions span at most the turns
    # between the shortest and the longest cable (either side of 0).
    span_rev = abs(hi - lo)
    if span_rev > 0.0:
        ulp_rev = 2.0 ** (math.floor(math.log2(span_rev)) - 23)
        metres_per_motor_rev = abs(lim.max_cable_m - lim.min_cable_m) / span_rev
        res_m = ulp_rev * metres_per_motor_rev
        if res_m > FLOAT32_RESOLUTION_LIMIT_M:
            raise ConfigError(
                source,
                key,
                f"float32 motor turns resolve only {res_m * 1e3:.3g} mm of cable over "
                f"{span_rev:.6g} turns (limit {FLOAT32_RESOLUTION_LIMIT_M * 1e3:g} mm): "
                "use fewer metres per motor turn or a shorter cable range",
            )


def _parse_loop(lt: _Table) -> LoopConfig:
    """The `[loop]` table (problems are recorded in the table's error list)."""
    lt.finish(tuple(LoopConfig.__dataclass_fields__))
    d_loop = LoopConfig()
    loop = LoopConfig(
        rate_hz=lt.number("rate_hz", d_loop.rate_hz, ge=1.0, le=2000.0),
        realtime=lt.boolean("realtime", d_loop.realtime),
        gc_freeze=lt.boolean("gc_freeze", d_loop.gc_freeze),
        publish_every=lt.integer("publish_every", d_loop.publish_every, ge=1, le=100_000),
        encoder_rtr=lt.boolean("encoder_rtr", d_loop.encoder_rtr),
        rt_priority=lt.integer("rt_priority", d_loop.rt_priority, ge=1, le=99),
        auto_arm=lt.boolean("auto_arm", False) if lt.has("auto_arm") else None,
        torque_telemetry=lt.string("torque_telemetry", d_loop.torque_telemetry) or "off",
        torque_rtr_period_s=lt.number(
            "torque_rtr_period_s", d_loop.torque_rtr_period_s, gt=0.0, le=10.0
        ),
        stretch_tensions=lt.string("stretch_tensions", d_loop.stretch_tensions) or "planned",
    )
    if loop.stretch_tensions not in STRETCH_TENSIONS:
        lt.fail(
            "stretch_tensions",
            f"must be one of {', '.join(STRETCH_TENSIONS)}, got {loop.stretch_tensions!r}",
        )
    if loop.torque_telemetry not in TORQUE_TELEMETRY:
        lt.fail(
            "torque_telemetry",
            f"must be one of {', '.join(TORQUE_TELEMETRY)}, got {loop.torque_telemetry!r}",
        )
    return loop


def _parse_sim(st: _Table, interface: str, loop: LoopConfig) -> SimConfig:
    """The `[sim]` table; its defaults depend on the bus interface and the loop rate."""
    st.finish(tuple(SimConfig.__dataclass_fields__))
    d_sim = SimConfig()
    period_s = 1.0 / loop.rate_hz
    sim = SimConfig(
        enabled=st.boolean("enabled", interface == "virtual"),
        encoder_period_s=st.number("encoder_period_s", d_sim.encoder_period_s, gt=0.0, le=1.0),
        heartbeat_period_s=st.number(
            "heartbeat_period_s", d_sim.heartbeat_period_s, gt=0.0, le=10.0
        ),
        max_velocity_rps=st.number("max_velocity_rps", d_sim.max_velocity_rps, gt=0.0),
        max_accel_rps2=st.number("max_accel_rps2", d_sim.max_accel_rps2, gt=0.0),
        tick_s=st.number("tick_s", d_sim.tick_s, gt=0.0, le=0.1),
        watchdog_timeout_s=st.number(
            "watchdog_timeout_s",
            max(d_sim.watchdog_timeout_s, WATCHDOG_DEFAULT_PERIODS * period_s),
            ge=0.0,
            le=10.0,
        ),
        plant=st.string("plant", d_sim.plant) or d_sim.plant,
        cable_ea_n=st.number("cable_ea_n", d_sim.cable_ea_n, gt=0.0),
        cable_mass_kg_per_m=(
            st.number("cable_mass_kg_per_m", ge=0.0) if st.has("cable_mass_kg_per_m") else None
        ),
        cable_damping_ratio=st.number(
            "cable_damping_ratio", d_sim.cable_damping_ratio, ge=0.0, le=1.0
        ),
        effector_damping_n_s_per_m=(
            st.number("effector_damping_n_s_per_m", ge=0.0)
            if st.has("effector_damping_n_s_per_m")
            else None
        ),
        torque_period_s=st.number("torque_period_s", d_sim.torque_period_s, ge=0.0, le=10.0),
    )
    if sim.plant not in SIM_PLANTS:
        st.fail("plant", f"must be one of {', '.join(SIM_PLANTS)}, got {sim.plant!r}")
    wd = sim.watchdog_timeout_s
    if 0.0 < wd < WATCHDOG_MIN_PERIODS * period_s:
        st.fail(
            "watchdog_timeout_s",
            f"{wd:g} s is shorter than {WATCHDOG_MIN_PERIODS:g} loop periods "
            f"({WATCHDOG_MIN_PERIODS * period_s:g} s at {loop.rate_hz:g} Hz); 0 turns it off",
        )
    return sim


def _parse_faults(ft: _Table, loop: LoopConfig, sim: SimConfig) -> FaultConfig:
    """The `[faults]` table, checked against the loop rate and the simulated drives."""
    period_s = 1.0 / loop.rate_hz
    ft.finish(tuple(FaultConfig.__dataclass_fields__))
    d_f = FaultConfig()
    faults = FaultConfig(
        stale_timeout_s=ft.number("stale_timeout_s", d_f.stale_timeout_s, gt=0.0, le=10.0),
        heartbeat_timeout_s=ft.number(
            "heartbeat_timeout_s", d_f.heartbeat_timeout_s, gt=0.0, le=60.0
        ),
        residual_max_m=ft.number("residual_max_m", d_f.residual_max_m, gt=0.0),
        tracking_max_m=ft.number("tracking_max_m", d_f.tracking_max_m, gt=0.0),
        arm_timeout_s=ft.number("arm_timeout_s", d_f.arm_timeout_s, gt=0.0, le=60.0),
        bus_error_timeout_s=ft.number(
            "bus_error_timeout_s", d_f.bus_error_timeout_s, ge=0.0, le=10.0
        ),
        slack_tension_n=(
            ft.number("slack_tension_n", ge=0.0) if ft.has("slack_tension_n") else None
        ),
        slack_time_s=ft.number("slack_time_s", d_f.slack_time_s, ge=0.0, le=10.0),
    )
    if faults.stale_timeout_s < 2.0 * period_s:
        ft.fail(
            "stale_timeout_s",
            f"{faults.stale_timeout_s:g} s is shorter than two loop periods "
            f"({2.0 * period_s:g} s at {loop.rate_hz:g} Hz)",
        )
    if sim.enabled and faults.stale_timeout_s < 2.0 * sim.encoder_period_s:
        ft.fail(
            "stale_timeout_s",
            f"{faults.stale_timeout_s:g} s is shorter than two simulated encoder periods "
            f"(sim.encoder_period_s = {sim.encoder_period_s:g} s)",
        )
    if sim.enabled and faults.heartbeat_timeout_s < 2.0 * sim.heartbeat_period_s:
        ft.fail(
            "heartbeat_timeout_s",
            f"{faults.heartbeat_timeout_s:g} s is shorter than two simulated heartbeat periods "
            f"(sim.heartbeat_period_s = {sim.heartbeat_period_s:g} s)",
        )
    return faults


def parse_config(data: Mapping[str, Any], source: str, text: str | None = None) -> RobotConfig:
    """Validate an already-parsed TOML mapping and return the `RobotConfig`.

    `source` names the origin (file path) in error messages; `text` is the TOML text the
    mapping was read from (None: written from the mapping, `tomltext.to_toml`). Raises one
    ConfigError listing every problem found (each naming the key path): unknown keys, wrong
    types or units, out-of-range values, duplicate node ids, unusable anchor geometry, an
    unknown bus interface or interface option, a bad Zenoh endpoint or file, failed
    cross-checks, a top speed that cannot be meant (`controller.core.scale`).
    """
    errs = _Errors(source)
    if not isinstance(data, Mapping):
        raise ConfigError(source, "", f"must be a table, got {_tname(data)}")
    top = _Table(data, "", errs)
    top.finish(_TOP_KEYS)
    name = top.string("name", _TOP_DEFAULTS["name"]) or _TOP_DEFAULTS["name"]
    if not _NAME_RE.match(name):
        top.fail("name", f"must match {_NAME_RE.pattern} (used in paths and keys), got {name!r}")
        name = "default"

    mark = errs.mark()
    drive, family = _parse_drive(top)
    drive_ok = errs.clean_since(mark)
    reels = _parse_reels(top, data, errs, family)
    geometry: Geometry | None = None
    if reels is not None and len(reels) > MAX_CABLES:
        errs.add(
            "reels",
            f"{len(reels)} reels: a point effector takes 3 to {MAX_CABLES} cables",
        )
        reels = None
    if reels is not None:
        try:
            geometry = Geometry([r.anchor_m for r in reels])
        except SingularGeometryError as exc:
            errs.add("reels[*].anchor_m", f"singular anchors: {exc} (anchors numbered from 1)")
        except (KinematicsError, ArithmeticError, ValueError) as exc:
            errs.add("reels[*].anchor_m", str(exc))

    bus = _parse_bus(top)

    lt = top.sub("loop")
    loop = _parse_loop(lt)

    # ---- limits: no defaults in a file (a safe limit depends on the robot)
    mark = errs.mark()
    if top.has("limits"):
        limits = _parse_limits(top.sub("limits"))
    else:
        errs.add("limits", "missing (every robot needs its own [limits])")
        limits = LimitsConfig()  # a stand-in: the configuration is refused
    limits_ok = errs.clean_since(mark)
    if limits_ok and geometry is not None and reels is not None:
        # Among the anchors (some at or below the workspace: a Hangprinter), or hanging.
        geometry = layout_geometry([r.anchor_m for r in reels], limits)
        g = geometry
        errs.check("limits", lambda: _check_limits(limits, g, source))
        for i, r in enumerate(reels):
            errs.check(f"reels[{i}]", functools.partial(_check_reel_range, r, i, limits, source))
    limits_ok = limits_ok and errs.clean_since(mark)
    if limits_ok and geometry is not None:
        box = Workspace.from_limits(limits, geometry).box()
        why = speed_scale_problem(limits.max_speed_mps, box)
        if why is not None:
            errs.add("limits.max_speed_mps", why)

    st = top.sub("sim")
    sim = _parse_sim(st, bus.interface, loop)
    ft = top.sub("faults")
    faults = _parse_faults(ft, loop, sim)

    ht = top.sub("homing")
    homing = _parse_homing(ht, name, limits if limits_ok else None, geometry)
    pup = homing.power_up_position_m

    zenoh = _parse_zenoh(top, name)
    ros2 = _parse_ros2(top)
    gcode = _parse_gcode(top, limits if limits_ok else None)

    if family is not None:
        limits_used = limits if limits_ok else None
        _check_drive(top, drive, family, drive_ok, loop, faults, limits_used, reels)
        if drive_ok and reels:  # the bus must carry the tick's frames (drivers.busload)
            refusal = busload.for_config(drive, len(reels), loop, bus).refusal()
            if refusal is not None:
                errs.add("loop.rate_hz", refusal)
    payload, tension = _parse_statics(top, errs, limits, limits_ok, reels, geometry, pup)
    _check_telemetry_and_plant(
        top, lt, ft, st, ht, loop, faults, sim, bus.interface, drive, payload, tension, pup
    )
    _check_stretch(top, lt, errs, loop, reels)
    _check_sag(top, errs, loop, reels, limits if limits_ok else None, tension, geometry)
    shaper = _parse_shaper(top, reels, payload)

    errs.raise_if_any()
    assert reels is not None and geometry is not None  # no problems: both were built
    return RobotConfig(
        name=name,
        reels=reels,
        geometry=geometry,
        bus=bus,
        loop=loop,
        limits=limits,
        faults=faults,
        homing=homing,
        zenoh=zenoh,
        sim=sim,
        source=source,
        drive=drive,
        payload=payload,
        tension=tension,
        ros2=ros2,
        gcode=gcode,
        shaper=shaper,
        text=_robot_text(data) if text is None else text,
    )


def _robot_text(data: Mapping[str, Any]) -> str:
    """The TOML text of a valid robot mapping; "" if it holds a value TOML cannot write (a
    robot built in code with, say, a tuple of numpy floats: it then has no description)."""
    try:
        return to_toml(data)
    except (TypeError, ValueError):
        return ""


def _parse_shaper(
    top: _Table, reels: Sequence[ReelConfig] | None, payload: PayloadConfig | None
) -> ShaperConfig:
    """The `[shaper]` table. Without `type` the default train shapes where the modes are known
    (`frequency_hz`, or every reel's `cable_ea_n` and a payload), else nothing is shaped; a
    type other than "off" needs them known. An unknown type gets a did-you-mean."""
    sh = top.sub("shaper")
    sh.finish(tuple(ShaperConfig.__dataclass_fields__))
    d = ShaperConfig()
    damping = sh.number("damping_ratio", d.damping_ratio, ge=0.0, le=MAX_DAMPING_RATIO)
    freq: float | None = None
    if sh.has("frequency_hz"):
        freq = sh.number("frequency_hz", None, ge=MIN_FREQUENCY_HZ, le=MAX_FREQUENCY_HZ)
    scale = sh.number("frequency_scale", d.frequency_scale, ge=0.2, le=5.0)
    passes = sh.integer("passes", d.passes, ge=1, le=MAX_PASSES)
    model = (
        reels is not None and payload is not None and all(r.cable_ea_n is not None for r in reels)
    )
    known = freq is not None or model
    kind = sh.string("type", None) if sh.has("type") else None
    if kind is None:
        kind = d.type if known else "off"
    elif kind not in SHAPER_TYPES:
        near = closest(kind.lower(), SHAPER_TYPES)
        hint = f" (did you mean {near!r}?)" if near else ""
        sh.fail("type", f"unknown shaper type {kind!r}{hint}; one of {', '.join(SHAPER_TYPES)}")
        kind = "off"
    elif kind != "off" and not known:
        sh.fail(
            "type",
            f"{kind!r} needs the modes: give shaper.frequency_hz, or every reel's cable_ea_n "
            "and [payload] for the model's",
        )
    return ShaperConfig(kind, damping, freq, scale, passes)


def _parse_gcode(top: _Table, limits: LimitsConfig | None) -> GcodeConfig:
    """The `[gcode]` table (`cablebot gcode`); `rapid_speed_mps` is checked against
    `limits.max_speed_mps` when the limits are valid (None: they are not)."""
    gt = top.sub("gcode")
    gt.finish(tuple(GcodeConfig.__dataclass_fields__))
    d = GcodeConfig()
    origin = gt.vec3("origin_m", required=False) or d.origin_m
    home = gt.vec3("home_m", required=False)
    units = gt.string("units", d.units) or d.units
    if units not in GCODE_UNITS:
        gt.fail("units", f"must be one of {', '.join(GCODE_UNITS)}, got {units!r}")
    dialect = gt.string("dialect", d.dialect) or d.dialect
    if dialect not in GCODE_DIALECTS:
        gt.fail("dialect", f"must be one of {', '.join(GCODE_DIALECTS)}, got {dialect!r}")
    tol = gt.number("arc_tolerance_m", d.arc_tolerance_m, gt=0.0)
    rapid: float | None = None
    if gt.has("rapid_speed_mps"):
        rapid = gt.number("rapid_speed_mps", None, gt=0.0)
        if limits is not None and math.isfinite(rapid) and rapid > limits.max_speed_mps:
            gt.fail(
                "rapid_speed_mps",
                f"{rapid:g} m/s exceeds limits.max_speed_mps ({limits.max_speed_mps:g} m/s)",
            )
    return GcodeConfig(origin, units, home, tol, rapid, dialect)


def _parse_homing(
    ht: _Table, name: str, limits: LimitsConfig | None, geometry: Geometry | None
) -> HomingConfig:
    """The `[homing]` table; the power-up pose is checked against `limits` (None: the limits
    are not valid themselves) and the geometry."""
    ht.finish(tuple(HomingConfig.__dataclass_fields__))
    pup = ht.vec3("power_up_position_m", required=False)
    state_file = ht.string("state_file", None)
    if pup is not None and limits is not None and geometry is not None:
        p, g, lim = pup, geometry, limits
        ht.errs.check(
            "homing.power_up_position_m",
            lambda: _raise_point_problem(ht, "power_up_position_m", p, lim, g),
        )
    if state_file is not None:
        try:
            state_file = os.path.expanduser(state_file.format(name=name))
        except (KeyError, IndexError, ValueError):
            ht.fail("state_file", f"only {{name}} may be substituted, got {state_file!r}")
    d_h = HomingConfig()
    pt = {
        key: ht.number(key, getattr(d_h, key), gt=0.0, le=le)
        for key, le in (
            ("pretension_still_mps", 1.0),
            ("pretension_settle_s", 60.0),
            ("pretension_timeout_s", 3600.0),
            ("pretension_max_travel_m", 1000.0),
            ("pretension_speed_mps", 10.0),
        )
    }
    return HomingConfig(pup, state_file, **pt)


def _check_stretch(
    top: _Table, lt: _Table, errs: _Errors, loop: LoopConfig, reels: Sequence[ReelConfig] | None
) -> None:
    """Cable stretch (`[[reels]] cable_ea_n`) needs `[payload]` (the tensions it follows);
    `loop.stretch_tensions = "measured"` needs torque telemetry and a cable that stretches."""
    stretchy = [i for i, r in enumerate(reels or ()) if r.cable_ea_n is not None]
    if stretchy and not top.has("payload"):
        for i in stretchy:
            errs.add(
                f"reels[{i}].cable_ea_n",
                "needs [payload] mass_kg (the stretch follows the tensions that hold it)",
            )
    if loop.stretch_tensions == "measured":
        if loop.torque_telemetry == "off":
            lt.fail("stretch_tensions", '"measured" needs loop.torque_telemetry on')
        if reels is not None and not stretchy:
            lt.fail("stretch_tensions", '"measured" does nothing: no reel has cable_ea_n')


def _check_sag(
    top: _Table,
    errs: _Errors,
    loop: LoopConfig,
    reels: Sequence[ReelConfig] | None,
    limits: LimitsConfig | None,
    tension: TensionLimits | None,
    geometry: Geometry | None,
) -> None:
    """Heavy cables (`[[reels]] cable_mass_kg_per_m`) need `[payload]` and planned tensions
    for the pose; a cable too heavy to hang within the tension limit anywhere in the workspace
    is refused with the pose (`cable_self_weight_problem`)."""
    heavy = [i for i, r in enumerate(reels or ()) if r.cable_mass_kg_per_m]
    if not heavy:
        return
    if not top.has("payload"):
        for i in heavy:
            errs.add(
                f"reels[{i}].cable_mass_kg_per_m",
                "needs [payload] mass_kg (the sag follows the tensions that hold it)",
            )
        return
    if loop.stretch_tensions == "measured":
        errs.add(
            "loop.stretch_tensions",
            '"measured" is not modelled with heavy cables (reels\' cable_mass_kg_per_m): '
            'use "planned"',
        )
    if reels is None or limits is None or tension is None or geometry is None:
        return
    for i, key, problem in cable_self_weight_problems(reels, limits, tension, geometry):
        errs.add(f"reels[{i}].{key}", problem)


def _check_telemetry_and_plant(
    top: _Table,
    lt: _Table,
    ft: _Table,
    st: _Table,
    ht: _Table,
    loop: LoopConfig,
    faults: FaultConfig,
    sim: SimConfig,
    bus_interface: str,
    drive: DriveConfig,
    payload: PayloadConfig | None,
    tension: TensionLimits | None,
    pup: Vec3 | None,
) -> None:
    """Cross-checks of torque telemetry, the slack fault and the simulated plant with the
    drives, the bus, the payload and the power-up pose (problems recorded in the tables)."""
    if loop.torque_telemetry != "off" and kinematic_sim(sim, bus_interface):
        where = "sim.enabled" if sim.enabled else f"simulated drives on {bus_interface}"
        lt.fail(
            "torque_telemetry",
            f'"{loop.torque_telemetry}" with the kinematic simulator ({where}): it carries '
            'no load and reports no torque; use sim.plant = "physical"',
        )
    if faults.slack_tension_n is not None:
        if loop.torque_telemetry == "off":
            ft.fail("slack_tension_n", 'needs measured tensions: loop.torque_telemetry is "off"')
        if not top.has("payload"):
            ft.fail("slack_tension_n", "needs [payload] mass_kg (tension limits need a load)")
        elif tension is not None and not faults.slack_tension_n < tension.min_n:
            ft.fail(
                "slack_tension_n",
                f"{faults.slack_tension_n:g} N must be below limits.min_tension_n "
                f"({tension.min_n:g} N): every holding pose would be slack",
            )
    if sim.plant == "physical":
        if drive.kind != "odrive":
            st.fail(
                "plant",
                f'"physical" needs simulated ODrives (they report torques); drive.kind is '
                f"{drive.kind!r}",
            )
        if payload is None and not top.has("payload"):
            st.fail("plant", '"physical" needs [payload] mass_kg (what the cables carry)')
        if pup is None and not ht.has("power_up_position_m"):
            st.fail(
                "plant",
                '"physical" needs homing.power_up_position_m (where the simulated effector starts)',
            )


MAX_CABLES = 8
"""The most cables a robot file may have (RepRapFirmware's Hangprinter takes up to eight)."""

MAX_QUEUED_POINTS = 10_000_000
"""The largest `[limits] max_queued_points` (a queued point costs about 150 bytes of planner
memory: 1.5 GB); the smallest is one path command's `MAX_PATH_POINTS`, so a full path fits."""


def _parse_limits(mt: _Table) -> LimitsConfig:
    mt.finish(tuple(LimitsConfig.__dataclass_fields__))
    d_lim = LimitsConfig()
    max_speed = mt.number("max_speed_mps", required=True, gt=0.0)
    return LimitsConfig(
        xy_margin_m=mt.number("xy_margin_m", required=True, ge=0.0),
        floor_z_m=mt.number("floor_z_m", required=True),
        top_margin_m=mt.number("top_margin_m", required=True, ge=0.0),
        min_cable_m=mt.number("min_cable_m", required=True, gt=0.0),
        max_cable_m=mt.number("max_cable_m", required=True, gt=0.0),
        max_cable_speed_mps=mt.number("max_cable_speed_mps", required=True, gt=0.0),
        max_speed_mps=max_speed,
        max_accel_mps2=mt.number("max_accel_mps2", required=True, gt=0.0),
        default_speed_mps=mt.number("default_speed_mps", max_speed, gt=0.0),
        velocity_timeout_s=mt.number("velocity_timeout_s", d_lim.velocity_timeout_s, gt=0.0),
        junction_deviation_m=mt.number("junction_deviation_m", d_lim.junction_deviation_m, gt=0.0),
        max_queued_points=mt.integer(
            "max_queued_points", d_lim.max_queued_points, ge=MAX_PATH_POINTS, le=MAX_QUEUED_POINTS
        ),
        min_tension_n=mt.number("min_tension_n", ge=0.0) if mt.has("min_tension_n") else None,
        max_tension_n=mt.number("max_tension_n", gt=0.0) if mt.has("max_tension_n") else None,
        tension_margin_n=mt.number("tension_margin_n", d_lim.tension_margin_n, ge=0.0),
        ceiling_z_m=mt.number("ceiling_z_m") if mt.has("ceiling_z_m") else None,
        print_radius_m=mt.number("print_radius_m", gt=0.0) if mt.has("print_radius_m") else None,
    )


_TENSION_KEYS = ("min_tension_n", "max_tension_n", "tension_margin_n")


def _parse_statics(
    top: _Table,
    errs: _Errors,
    limits: LimitsConfig,
    limits_ok: bool,
    reels: tuple[ReelConfig, ...] | None,
    geometry: Geometry | None,
    power_up_m: Vec3 | None,
) -> tuple[PayloadConfig | None, TensionLimits | None]:
    """`[payload]` and the tension limits; (None, None) without `[payload]` (then no tension key
    may be set: it would do nothing). Cross-checks, when their inputs are clean: a usable
    tension range and a tension-feasible power-up pose."""
    if not top.has("payload"):
        lim_raw = top.raw("limits") if top.has("limits") else {}
        for k in _TENSION_KEYS:
            if isinstance(lim_raw, Mapping) and k in lim_raw:
                errs.add(f"limits.{k}", "needs [payload] mass_kg (tension limits need a load)")
        for i, r in enumerate(reels or ()):
            if r.max_torque_nm is not None:
                errs.add(
                    f"reels[{i}].max_torque_nm",
                    "needs [payload] mass_kg (tension limits need a load)",
                )
        return None, None
    pt = top.sub("payload")
    pt.finish(tuple(PayloadConfig.__dataclass_fields__))
    mark = errs.mark()
    mass = pt.number("mass_kg", required=True, gt=0.0)
    if limits_ok and limits.min_tension_n is None:
        errs.add("limits.min_tension_n", "missing (required with [payload])")
    if not (errs.clean_since(mark) and limits_ok and reels is not None and geometry is not None):
        return None, None
    payload = PayloadConfig(mass_kg=mass)
    max_n, max_source = math.inf, ""
    if limits.max_tension_n is not None:
        max_n, max_source = limits.max_tension_n, "limits.max_tension_n"
    for i, r in enumerate(reels):
        if r.max_torque_nm is None:
            continue
        try:
            t = r.reel.max_tension_n(r.max_torque_nm, limits.min_cable_m, limits.max_cable_m)
        except ValueError as exc:  # already reported by the reel range check
            errs.add(f"reels[{i}].max_torque_nm", f"no tension bound: {exc}")
            return None, None
        if t < max_n:
            max_n, max_source = t, f"reels[{i}].max_torque_nm"
    if not math.isfinite(max_n):
        errs.add(
            "limits.max_tension_n",
            "missing (required with [payload] unless every reel has max_torque_nm)",
        )
        return None, None
    if any(r.max_torque_nm is None for r in reels) and limits.max_tension_n is None:
        missing = ", ".join(f"reels[{i}]" for i, r in enumerate(reels) if r.max_torque_nm is None)
        errs.add(
            "limits.max_tension_n",
            f"missing (required with [payload] unless every reel has max_torque_nm; "
            f"{missing} has none)",
        )
        return None, None
    lo = limits.min_tension_n
    assert lo is not None
    margin = limits.tension_margin_n
    if not lo + margin < max_n - margin:
        errs.add(
            "limits.min_tension_n",
            f"{lo:g} N + tension_margin_n ({margin:g} N) leaves no tension range below the "
            f"maximum {max_n:.4g} N (from {max_source}) minus the margin",
        )
        return None, None
    tension = TensionLimits(min_n=lo, max_n=max_n, margin_n=margin, max_source=max_source)
    if power_up_m is not None:
        problem = tension_problem(geometry, payload, tension, power_up_m, reels)
        if problem is not None:
            errs.add("homing.power_up_position_m", problem)
    return payload, tension


def tension_check(
    payload: PayloadConfig,
    tension: TensionLimits,
    geometry: Geometry,
    reels: Sequence[ReelConfig] = (),
) -> TensionCheck:
    """The tension rule of this payload and these limits: with heavy `reels` (a
    `cable_mass_kg_per_m`) the rule with the cables' weight
    (`controller.core.sag_plan.SagTensionCheck`), else the straight cables'
    (`controller.core.statics.TensionCheck`).

    Raises StaticsInputError only for values validation refuses."""
    weights = [(r.cable_mass_kg_per_m or 0.0) * G_MPS2 for r in reels]
    if any(w > 0.0 for w in weights):
        from controller.core.sag_plan import SagTensionCheck

        return SagTensionCheck(
            geometry.anchors_m,
            payload.mass_kg,
            tension.min_n,
            tension.max_n,
            tension.margin_n,
            tension.max_source,
            weights,
            [r.cable_ea_n for r in reels],
        )
    return TensionCheck(
        geometry.anchors_m,
        payload.mass_kg,
        tension.min_n,
        tension.max_n,
        tension.margin_n,
        tension.max_source,
    )


def tension_problem(
    geometry: Geometry,
    payload: PayloadConfig,
    tension: TensionLimits,
    point_m: Vec3,
    reels: Sequence[ReelConfig] = (),
) -> str | None:
    """Why the cables cannot hold `payload` at `point_m` within the tension limits and their
    margin (with heavy `reels`, their weight too), or None when they can. Raises nothing."""
    return tension_check(payload, tension, geometry, reels).check(point_m)


def _parse_reels(
    top: _Table, data: Mapping[str, Any], errs: _Errors, family: registry.Family | None
) -> tuple[ReelConfig, ...] | None:
    """The [[reels]] array; None (problems recorded) unless every reel is usable."""
    if "reels" not in data:
        errs.add("reels", "missing (need at least 3 [[reels]] tables)")
        return None
    reels_raw = top.raw("reels")
    if not isinstance(reels_raw, list):
        errs.add("reels", f"must be an array of tables ([[reels]]), got {_tname(reels_raw)}")
        return None
    if len(reels_raw) < 3:
        errs.add("reels", f"need at least 3 reels, got {len(reels_raw)}")
    parsed = [_parse_reel(_Table(r, f"reels[{i}]", errs), family) for i, r in enumerate(reels_raw)]
    seen: dict[int, int] = {}
    duplicate = False
    for i, raw in enumerate(reels_raw):  # raw: a reel with another problem still has its id
        node = raw.get("node_id") if isinstance(raw, Mapping) else None
        if not isinstance(node, int) or isinstance(node, bool):
            continue
        if node in seen:
            errs.add(f"reels[{i}].node_id", f"duplicate node id {node} (also reels[{seen[node]}])")
            duplicate = True
        else:
            seen[node] = i
    good = [r for r in parsed if r is not None]
    if len(good) != len(parsed) or len(good) < 3 or duplicate:
        return None
    return tuple(good)


def _parse_drive(top: _Table) -> tuple[DriveConfig, registry.Family | None]:
    """The [drive] table: the family named by `kind` and its options from the registry's
    table; the family is None (problem recorded) when `kind` names none."""
    t = top.sub("drive")
    kind = t.string("kind", registry.DEFAULT_KIND) or registry.DEFAULT_KIND
    family = registry.FAMILIES.get(kind)
    if family is None:
        t.fail("kind", registry.unknown_family_problem(kind))
        return DriveConfig(kind), None
    known = {"kind", *(o.name for o in family.options)}
    for k in t.data:
        if k in known:
            continue
        owners = sorted(
            f.name for f in registry.FAMILIES.values() if k in {o.name for o in f.options}
        )
        problem = _unknown(k, known)
        if owners:
            problem += f" ({k} is an option of [drive] kind = {owners[0]!r}, not {kind!r})"
        t.fail(k, problem)
    options: dict[str, Any] = {}
    for o in family.options:
        if not t.has(o.name) and not o.required and o.default is None:
            continue  # no value: the driver's own default applies
        if o.kind == "number":
            default = None if o.default is None else float(o.default)
            value: Any = t.number(o.name, default, gt=o.gt, ge=o.ge, le=o.le, required=o.required)
        elif o.kind == "bool":
            value = t.boolean(o.name, bool(o.default))
        else:
            text = t.string(o.name, None if o.default is None else str(o.default))
            if text is None:
                continue
            value = os.path.expanduser(text)
            if not Path(value).is_file():
                t.fail(o.name, f"no such file: {value}")
        options[o.name] = value
    return DriveConfig(kind, MappingProxyType(options)), family


def _check_drive(
    top: _Table,
    drive: DriveConfig,
    family: registry.Family,
    drive_ok: bool,
    loop: LoopConfig,
    faults: FaultConfig,
    limits: LimitsConfig | None,
    reels: Sequence[ReelConfig] | None,
) -> None:
    """Cross-checks of the drive family with the loop, faults and reels (see the module
    docstring); run only on values that are valid themselves (`drive_ok`: the [drive] table
    was)."""
    errs = top.errs
    opts = drive.options
    if loop.encoder_rtr and family.name != "odrive":
        errs.add(
            "loop.encoder_rtr",
            f"applies to ODrive drives only ([drive] kind = {family.name!r} drives send their "
            "positions every cycle)",
        )
    hb = opts.get("heartbeat_period_s")
    if drive_ok and isinstance(hb, float) and faults.heartbeat_timeout_s < 2.0 * hb:
        errs.add(
            "faults.heartbeat_timeout_s",
            f"{faults.heartbeat_timeout_s:g} s is shorter than two drive heartbeat periods "
            f"(drive.heartbeat_period_s = {hb:g} s)",
        )
    cpr = opts.get("counts_per_rev")
    if drive_ok and isinstance(cpr, float) and limits is not None and reels:
        for i, r in enumerate(reels):
            try:
                span_rev = abs(
                    r.reel.position_rev(limits.max_cable_m)
                    - r.reel.position_rev(limits.min_cable_m)
                )
            except (ValueError, ArithmeticError):
                continue  # reported by the reel range check
            if span_rev * cpr > 2**31 - 1:
                errs.add(
                    f"reels[{i}]",
                    f"{span_rev:.6g} motor turns over limits.min_cable_m..max_cable_m are "
                    f"{span_rev * cpr:.4g} position counts at drive.counts_per_rev = {cpr:g}: "
                    "beyond the drives' 32-bit position",
                )
    if drive_ok:
        for key, problem in family.check_options(opts, 1.0 / loop.rate_hz):
            errs.add(key, problem)


def _check_limits(lim: LimitsConfig, geometry: Geometry, source: str) -> None:
    """Raise ConfigError (naming the `limits.` keys) if the limits leave no workspace or no
    cable range (`Workspace` decides), or the default speed exceeds the maximum."""
    problems: list[ConfigError] = []
    try:
        Workspace.from_limits(lim, geometry)
    except WorkspaceError as exc:
        problems.append(ConfigError(source, f"limits.{exc.limit}", exc.detail))
    if lim.default_speed_mps > lim.max_speed_mps:
        problems.append(
            ConfigError(
                source,
                "limits.default_speed_mps",
                f"{lim.default_speed_mps:g} m/s exceeds max_speed_mps ({lim.max_speed_mps:g} m/s)",
            )
        )
    if problems:
        raise ConfigError.collected(source, problems)


def _raise_point_problem(
    t: _Table, name: str, p: Vec3, lim: LimitsConfig, geometry: Geometry
) -> None:
    problem = _point_problem(p, Workspace.from_limits(lim, geometry))
    if problem is not None:
        raise t.error(name, problem)


def _point_problem(p: Vec3, workspace: Workspace) -> str | None:
    """Why `p` is not an allowed pose (the workspace decides), in the words of the
    configuration keys, or None."""
    v = workspace.target_violation(p)
    if v is None:
        return None
    x, y, z = p
    if v.limit == "xy_margin_m" and workspace.hanging:
        return (
            f"({x:g}, {y:g}) m is outside the anchors' plan-view polygon shrunk by "
            f"limits.xy_margin_m ({v.bound:g} m)"
        )
    if v.limit == "xy_margin_m":
        return (
            f"({x:g}, {y:g}, {z:g}) m is outside the anchors' hull shrunk by "
            f"limits.xy_margin_m ({v.bound:g} m)"
        )
    if v.limit == "print_radius_m":
        return f"({x:g}, {y:g}) m is beyond limits.print_radius_m ({v.bound:g} m)"
    if v.limit == "floor_z_m":
        return f"z={z:g} m is below limits.floor_z_m ({v.bound:g} m)"
    if v.limit == "ceiling_z_m":
        return f"z={z:g} m is above limits.ceiling_z_m ({v.bound:g} m)"
    if v.limit == "top_margin_m" and not workspace.hanging:
        return f"z={z:g} m is above the highest anchor minus limits.top_margin_m ({v.bound:g} m)"
    if v.limit == "top_margin_m":
        return (
            f"z={z:g} m is above the anchor plane minus margin ({v.bound:g} m), "
            "the lowest anchor minus limits.top_margin_m"
        )
    if v.limit in ("min_cable_m", "max_cable_m"):
        return (
            f"cable {v.cable} would be {v.value:.4g} m, outside limits.min_cable_m..max_cable_m "
            f"({workspace.min_cable_m:g}..{workspace.max_cable_m:g} m)"
        )
    return v.reason
