"""``sitl``: fly a scenario in the 6-DOF simulator behind the ArduPlane-like mock autopilot."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from vdm_aero.errors import UserInputError

WORLD_TIME_PREFIX = "world time "  # --progress: one line per second of world time flown


def register(sub: Any) -> None:
    p = sub.add_parser(
        "sitl",
        help="run the mock autopilot on a simulated flight (software in the loop)",
        description="Fly scenario S (a shipped name or a YAML file) and speak MAVLink 2 on URL like ArduPlane: "
        "udpout:HOST:PORT, udpin:HOST:PORT, tcp:HOST:PORT, tcpin:HOST:PORT or pty (a serial pseudo-terminal "
        "pair; its path is printed). Named-value port messages start once the link has heard from the companion.",
    )
    p.add_argument("--list", action="store_true", help="list the shipped scenarios and exit")
    p.add_argument("--scenario", metavar="S")
    p.add_argument("--nav-scenario", metavar="NAME", help="instead of --scenario: one seed of a nav-drift benchmark "
                   "scenario (survey, loiter, ...) with its GNSS outage, the world the benchmark scores")  # fmt: skip
    p.add_argument("--seed", type=int, default=0, help="with --nav-scenario: the benchmark seed")
    p.add_argument("--outage-s", type=float, default=60.0, help="with --nav-scenario: the outage length [s]")
    p.add_argument("--world", choices=("kind", "harsh"), default="kind",
                   help="with --nav-scenario: the benchmark's world (harsh: every sourced sensor, Earth and fleet "
                   "effect, docs/flight-sim.md)")  # fmt: skip
    p.add_argument("--ports-rate-hz", type=float, help="with --nav-scenario: the port sampling rate (50..100 Hz)")
    p.add_argument("--ports-model", type=Path, metavar="DIR",
                   help="with --nav-scenario: the DEIM model whose ports the aircraft carries")  # fmt: skip
    p.add_argument("--connect", metavar="URL", default="udpout:127.0.0.1:14550")
    p.add_argument("--speed", type=float, default=1.0, help="world seconds per wall second; 0 = as fast as possible")
    p.add_argument("--duration-s", type=float, help="world time to fly [s] (default: the scenario's duration)")
    p.add_argument("--progress", action="store_true",
                   help="print 'world time T s' after each second of world time flown (a harness that acts at "
                   "world times follows this clock: on a slow machine the world falls behind --speed)")  # fmt: skip
    p.add_argument("--tlog", type=Path, help="write a MAVLink telemetry log of everything sent and received")
    p.add_argument("--truth", type=Path, help="write the truth trajectory (see docs/sitl.md)")
    p.add_argument("--signing-key", metavar="HEX", help="MAVLink 2 signing key, 64 hex digits (32 bytes)")
    p.add_argument("--require-signing", action="store_true", help="reject unsigned messages from the companion")
    p.add_argument("--ports-debug-array", action="store_true", help="also send the ports as one DEBUG_FLOAT_ARRAY")
    p.add_argument("--ports-array-only", action="store_true",
                   help="with --ports-debug-array: the array alone, no NAMED_VALUE_FLOAT (the Lua script's "
                   "VPP_MAV_CHAN)")  # fmt: skip
    p.add_argument(
        "--stream-rate", action="append", default=[], metavar="MSG=HZ", help="override a stream rate, repeatable"
    )
    p.add_argument(
        "--gcs-recording",
        action="store_true",
        help="a ground station records the tlog from the start, e.g. with --connect null to write a flight log "
        "for replay. It asks for every stream group at 4 Hz, as MAVProxy does, so the tlog holds ArduPilot's GCS "
        "set: RAW_IMU, SCALED_IMU2, SCALED_PRESSURE, SCALED_PRESSURE2, SYS_STATUS, GPS_RAW_INT, SERVO_OUTPUT_RAW, "
        "GLOBAL_POSITION_INT, LOCAL_POSITION_NED, ATTITUDE, SIMSTATE (the truth), AOA_SSA, VFR_HUD, SYSTEM_TIME "
        "and WIND at 4 Hz, HEARTBEAT at 1 Hz, and the scenario's pressure ports as NAMED_VALUE_FLOAT (they flow "
        "without a companion); no HIGHRES_IMU. --stream-rate overrides any of these",
    )
    p.add_argument(
        "--loop-rate-hz",
        type=float,
        metavar="HZ",
        help="the autopilot's SCHED_LOOP_RATE: no stream is sent faster (default 50, ArduPlane's)",
    )
    p.add_argument("--faults", type=Path, metavar="FILE",
                   help="scripted link and sensor faults in autopilot time (YAML, see docs/reliability.md): link "
                   "silence, GNSS jump/drift, stuck/NaN/missing/out-of-range ports, message floods")  # fmt: skip
    p.add_argument("--firmware", choices=("ardupilot", "px4"), default="ardupilot",
                   help="whose rules the mock follows: its HEARTBEAT, HIGHRES_IMU's differential pressure, and "
                   "how its EKF takes the companion's GPS_INPUT / ODOMETRY / GLOBAL_POSITION_SENSOR")  # fmt: skip
    p.add_argument("--px4-release", choices=("v1.16", "main"), default="v1.16",
                   help="with --firmware px4: v1.16 has no handler for GLOBAL_POSITION_SENSOR (296), main (2026) "
                   "takes it as auxiliary global position (sim/sitl/ekf2_judge.py)")  # fmt: skip
    p.add_argument("--viso", action="append", default=[], metavar="NAME=VALUE",
                   help="an ArduPilot VISO_ parameter the ExternalNav judge uses, as set on the autopilot (repeat): "
                   "VEL_M_NSE, POS_M_NSE, QUAL_MIN, SCALE, TYPE (default: ArduPilot's defaults)")  # fmt: skip
    p.add_argument("--json", action="store_true", help="print the run summary as JSON")
    p.set_defaults(func=run_sitl_cmd)

    q = sub.add_parser(
        "plot-flight",
        help="plot a flown trajectory from a SITL truth file, with its GNSS outage windows",
        description="Ground track (north/east, outage stretches highlighted), altitude and airspeed against time.",
    )
    q.add_argument("truth", type=Path, metavar="TRUTH")
    q.add_argument("--out", type=Path, required=True, metavar="FILE.png")
    q.set_defaults(func=run_plot_flight)


def _rates(items: list[str]) -> dict[str, float]:
    out = {}
    for item in items:
        name, sep, hz = item.partition("=")
        try:
            if not sep:
                raise ValueError
            out[name.strip().upper()] = float(hz)
        except ValueError:
            raise UserInputError(f"--stream-rate: expected MSG=HZ (e.g. ATTITUDE=50), got {item!r}") from None
    return out


_VISO_PARAMS = {"VEL_M_NSE": "vel_m_nse", "POS_M_NSE": "pos_m_nse", "QUAL_MIN": "qual_min", "SCALE": "scale",
                "TYPE": "type"}  # fmt: skip


def _viso(items: list[str]) -> dict[str, float]:
    """--viso NAME=VALUE pairs as :class:`~sim.sitl.extnav_judge.VisoParams` fields (integers where ArduPilot's
    parameter is one)."""
    out: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        key = _VISO_PARAMS.get(name.strip().upper().removeprefix("VISO_"))
        try:
            if key is None or not sep or not math.isfinite(v := float(value)):
                raise ValueError
        except ValueError:
            raise UserInputError(f"--viso: expected NAME=VALUE with NAME one of {', '.join(_VISO_PARAMS)}, "
                                 f"got {item!r}") from None  # fmt: skip
        out[key] = int(v) if key in ("qual_min", "type") else v
    return out


def _stream_rates(args: argparse.Namespace) -> dict[str, float]:
    """--stream-rate over what the recording ground station asks for (--gcs-recording)."""
    rates = _rates(args.stream_rate)
    if not args.gcs_recording:
        return rates
    from sim.sitl.streams import gcs_request_rates

    return {**gcs_request_rates(), **rates}


def run_sitl_cmd(args: argparse.Namespace) -> int:
    from sim.flight.scenario import load_scenario, scenario_names

    if args.list:
        for name in scenario_names():
            print(name)
        return 0
    if not args.scenario and not args.nav_scenario:
        raise UserInputError("sitl: give --scenario S or --nav-scenario NAME (or --list)")
    key = None
    if args.signing_key is not None:
        try:
            key = bytes.fromhex(args.signing_key)
        except ValueError:
            key = b""
        if len(key) != 32:
            raise UserInputError("--signing-key: expected 64 hex digits (a 32-byte MAVLink 2 signing key)")
    if args.require_signing and key is None:
        raise UserInputError("--require-signing needs --signing-key")
    if not (args.speed >= 0.0 and math.isfinite(args.speed)):
        raise UserInputError("--speed: must be a finite number ≥ 0 (0 = as fast as possible)")
    viso = _viso(args.viso)
    from sim.flight.world import FlightWorld
    from sim.sitl.autopilot import AutopilotOptions, DeadReckoningDrift, run_sitl
    from sim.sitl.ekf2_judge import Ekf2Rules
    from sim.sitl.extnav_judge import Ek3ExtNavRules, VisoParams
    from sim.sitl.faults import load_faults

    faults = load_faults(args.faults) if args.faults is not None else None
    scenario = load_scenario(args.scenario) if args.scenario else _nav_scenario(args)
    duration = args.duration_s if args.duration_s is not None else scenario.duration_s
    if not duration > 0:
        raise UserInputError("--duration-s: must be > 0")
    from sim.flight.world import FlightEnvelopeError

    for path in (args.tlog, args.truth):
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
    world = FlightWorld(scenario)
    try:
        summary = run_sitl(
            world,
            args.connect,
            speed=math.inf if args.speed == 0 else args.speed,
            duration_s=duration,
            tlog=args.tlog,
            truth=args.truth,
            stream_rates=_stream_rates(args) or None,
            signing_key=key,
            require_signing=args.require_signing,
            ports_as_debug_array=args.ports_debug_array,
            options=AutopilotOptions(
                gcs_recording=args.gcs_recording,
                firmware=args.firmware,
                ports_named_too=not args.ports_array_only,
                ekf2_rules=Ekf2Rules(release=args.px4_release, agp_handler=args.px4_release == "main"),
                extnav_rules=Ek3ExtNavRules(viso=VisoParams(**viso)),  # type: ignore[arg-type]
                faults=faults,
                # the autopilot's own drift drawn per benchmark seed, not the same draw on every flight
                drift=DeadReckoningDrift(seed=args.seed if args.nav_scenario else 0),
                **({"loop_rate_hz": args.loop_rate_hz} if args.loop_rate_hz else {}),
            ),
            on_ready=lambda where: print(f"mock autopilot on {where}, scenario {scenario.name}", flush=True),
            on_second=(lambda t: print(f"{WORLD_TIME_PREFIX}{t:.0f} s", flush=True)) if args.progress else None,
        )
    except FlightEnvelopeError as e:  # the simulated aircraft crashed or lost control: an outcome, not a bug
        print(f"vdm-aero: flight ended: {e}", file=sys.stderr)
        return 1
    if faults is not None:
        print(f"faults applied: {json.dumps(faults.applied)}", flush=True)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        sent = sum(summary["sent"].values())
        print(
            f"flew {summary['world_time_s']:.1f} s in {summary['wall_time_s']:.1f} s wall; sent {sent} messages, "
            f"received {sum(summary['received'].values())}; GPS_INPUT {summary['gps_input']}, "
            f"ODOMETRY {summary['odometry']}; link {'heard from' if summary['link_active'] else 'silent'}"
        )
    return 0


def _nav_scenario(args: argparse.Namespace) -> Any:
    """The benchmark's flight for (scenario, seed) with its outage in the world's GNSS receiver."""
    from dataclasses import replace

    from sim.flight.sensors import TimeWindow
    from vdm_aero_cli.nav_bench import AFTER_S, OUTAGE_START_S, SCENARIOS, bench_scenario

    if args.nav_scenario not in SCENARIOS:
        raise UserInputError(f"--nav-scenario: unknown {args.nav_scenario!r}; known: {', '.join(SCENARIOS)}")
    if SCENARIOS[args.nav_scenario][3] not in (None, "shear", "gradient", "payload"):
        raise UserInputError(f"--nav-scenario {args.nav_scenario}: its fault is injected into logs, not the world")
    if args.ports_model is None:
        raise UserInputError("--nav-scenario needs --ports-model DIR (the DEIM model that placed the ports)")
    if not args.outage_s > 0:
        raise UserInputError("--outage-s: must be > 0")
    duration = OUTAGE_START_S[1] + args.outage_s + AFTER_S + 5.0  # as the benchmark flies it
    if args.duration_s is not None:  # a longer flight (a soak) gets its winds and turbulence drawn that long
        duration = max(duration, args.duration_s + 5.0)
    sc, _, t_out = bench_scenario(args.nav_scenario, args.seed, args.ports_model, duration, args.world)
    gnss = replace(sc.gnss, outages=(TimeWindow(t_out, t_out + args.outage_s),))
    if args.ports_rate_hz is not None:
        if not 50.0 <= args.ports_rate_hz <= 100.0:
            raise UserInputError("--ports-rate-hz: the port transducers run at 50..100 Hz")
        sc = replace(sc, ports=replace(sc.ports, rate_hz=args.ports_rate_hz))
    print(f"nav scenario {args.nav_scenario} seed {args.seed}: GNSS outage {t_out:.2f} … {t_out + args.outage_s:.2f} s",
          flush=True)  # fmt: skip
    return replace(sc, gnss=gnss, duration_s=t_out + args.outage_s + AFTER_S)


def run_plot_flight(args: argparse.Namespace) -> int:
    plot_flight(args.truth, args.out)
    print(f"wrote {args.out}")
    return 0


def plot_flight(truth: Path, out: Path) -> None:
    """Ground track with the GNSS-outage stretches, altitude and airspeed against time."""
    import numpy as np

    from vdm_aero_cli.plots import _pyplot

    try:
        z = np.load(truth, allow_pickle=False)
        t, pos, outage = z["t_s"], z["pos_ned_m"], z["gnss_outage"].astype(bool)
        alt, tas = z["alt_m"], z["airspeed_m_s"]
    except (OSError, KeyError, ValueError) as e:
        raise UserInputError(f"{truth}: not a SITL truth file ({e})") from None
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(14, 6), gridspec_kw={"width_ratios": [1.2, 1]})
    ax = axes[0]
    ax.plot(pos[:, 1], pos[:, 0], "-", color="tab:blue", lw=1.0, label="GNSS available")
    ax.plot(np.where(outage, pos[:, 1], np.nan), np.where(outage, pos[:, 0], np.nan), "-", color="tab:red", lw=2.5,
            label="GNSS outage")  # fmt: skip
    ax.plot(pos[0, 1], pos[0, 0], "ko", label="start")
    ax.set(xlabel="east [m]", ylabel="north [m]", title=f"ground track, {t[-1]:.0f} s")
    ax.set_aspect("equal")
    ax.legend()
    ax2 = axes[1]
    ax2.plot(t, alt, color="tab:green", label="altitude AMSL [m]")
    ax3 = ax2.twinx()
    ax3.plot(t, tas, color="tab:purple", lw=0.8, label="airspeed [m/s]")
    ax3.set_ylabel("airspeed [m/s]")
    edges = np.flatnonzero(np.diff(np.concatenate([[0], outage.astype(int), [0]])))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        ax2.axvspan(t[a], t[b - 1], color="tab:red", alpha=0.15, label="GNSS outage" if a == edges[0] else None)
    ax2.set(xlabel="t [s]", ylabel="altitude AMSL [m]", title="altitude and airspeed")
    ax2.legend(loc="lower left")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
