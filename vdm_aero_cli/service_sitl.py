"""The companion service against the mock autopilot, as separate processes over UDP loopback (directly, or
through MAVProxy), scored against the world's truth and against the in-process benchmark on the same flight.

Used by the end-to-end tests, ``make demo`` and ``make bench``. Three processes: ``vdm-aero sitl
--nav-scenario`` (the world and the mock, with the outage in its GNSS receiver), optionally ``mavproxy.py``
routing between them, and ``vdm-aero serve``. Nothing of the world reaches the service except MAVLink.
"""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from vdm_aero.geodesy import LocalFrame
from vdm_aero.nav.filter import NavConfig

__all__ = ["ServiceRun", "ServiceTrack", "bench_reference", "run_service_sitl", "score_service"]

DEPLOY_CONFIG = Path(__file__).resolve().parent.parent / "deploy" / "config.yaml"
MAVPROXY = Path(sys.executable).parent / "mavproxy.py"
VDM_AERO = [sys.executable, "-m", "vdm_aero_cli.main"]


@dataclass(frozen=True)
class ServiceRun:
    """One service-against-mock flight: the models, the benchmark scenario and seed, the link."""

    design_data: Path
    deim: Path
    deim_nn: Path | None
    mode: str = "vdm"
    scenario: str = "survey"
    seed: int = 0
    outage_s: float = 60.0
    speed: float = 4.0
    via_mavproxy: bool = False
    ports_source: str = "named_value_float"
    ports_named_too: bool = True  # with ports_source debug_float_array: the mock sends the named values too
    streams: tuple[tuple[str, float], ...] = ()  # overrides of the autopilot's default streams (config: auto)
    stop_after_s: float | None = None  # world time to fly (default: to 20 s after the outage)
    ports_rate_hz: float | None = None  # default: the scenario's (50 Hz)
    signing_key_hex: str | None = None  # MAVLink 2 signing required on both sides (64 hex digits)
    # the autopilot's SCHED_LOOP_RATE, its fastest stream: raised from ArduPlane's 50 Hz as docs/service.md asks
    loop_rate_hz: float = 400.0
    solution: str | None = None  # outputs.solution (default: the shipped config's)
    # outputs.source_switch as (key, value) pairs, e.g. (("gnss_set", 1), ("extnav_set", 2)); None: as shipped
    source_switch: tuple[tuple[str, float], ...] | None = None
    autopilot: str = "ardupilot"  # the config's autopilot, and whose rules the mock follows (sitl --firmware)
    px4_release: str = "v1.16"  # as PX4: the release whose EKF2 the mock plays (sitl --px4-release)
    solution_hz: float | None = None  # outputs.solution_hz (default: the shipped config's)
    viso: tuple[tuple[str, float], ...] = ()  # the autopilot's VISO_ parameters as (name, value) (sitl --viso)


def nav_scenario_args(run: ServiceRun) -> list[str]:
    """``vdm-aero sitl``'s arguments for the benchmark flight of ``run``: scenario, seed, outage, ports."""
    return ["--nav-scenario", run.scenario, "--seed", str(run.seed), "--outage-s", f"{run.outage_s:g}",
            "--ports-model", str(run.deim)]  # fmt: skip


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def write_config(run: ServiceRun, work: Path, port: int, mag_field_ned_ut: tuple[float, float, float],
                 template: Path = DEPLOY_CONFIG) -> Path:  # fmt: skip
    """deploy/config.yaml (``template``: another checkout's) with the paths and link of this run (every other key
    as shipped)."""
    cfg = yaml.safe_load(template.read_text())
    cfg["connection"] = f"udpin://127.0.0.1:{port}"
    cfg["autopilot"] = run.autopilot
    cfg["models"].update(design_data=str(run.design_data), deim=str(run.deim),
                         deim_nn=str(run.deim_nn) if run.deim_nn else None)  # fmt: skip
    cfg["navigation"]["mode"] = run.mode
    cfg["navigation"]["mag_field_ned_ut"] = [float(v) for v in mag_field_ned_ut]
    # the receiver's data-sheet latency, as its user sets GPS_DELAY_MS on the autopilot and here (what the
    # benchmark's filters assume too)
    cfg["navigation"]["gnss_latency_s"] = NavConfig.gnss_latency_s
    cfg["ports"]["source"] = run.ports_source
    if run.streams:
        from firmware_bridge.config import DEFAULT_STREAMS

        cfg["streams"] = {**DEFAULT_STREAMS[cfg["autopilot"]], **dict(run.streams)}
    cfg["state"]["file"] = str(work / "state" / "filter-state.npz")
    cfg["nav_log"]["file"] = str(work / "state" / "nav.csv")
    cfg["status_every_s"] = 5
    if run.solution is not None:
        cfg["outputs"]["solution"] = run.solution
    if run.solution_hz is not None:
        cfg["outputs"]["solution_hz"] = run.solution_hz
    if run.source_switch is not None:
        cfg["outputs"]["source_switch"] = dict(run.source_switch)
    if run.signing_key_hex is not None:
        (work / "signing.key").write_text(run.signing_key_hex + "\n")
        cfg["signing"] = {"key_file": str(work / "signing.key"), "require": True}
    path = work / "config.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return path


def _cpu_s(pid: int) -> float:
    """User + system CPU time of a process [s] (/proc/PID/stat fields 14 and 15, in clock ticks)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _peak_rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024.0
    return math.nan


def _terminate(proc: subprocess.Popen[bytes], timeout_s: float = 20.0) -> int:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        return proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()


# no capabilities, none to gain (what the unit's User=vdm-aero and NoNewPrivileges=yes give on the aircraft)
UNPRIVILEGED = ("setpriv", "--no-new-privs", "--inh-caps=-all", "--ambient-caps=-all", "--bounding-set=-all", "--")


def start_service(config: Path, work: Path, *, env: dict[str, str] | None = None, unprivileged: bool = False,
                  wrap: Sequence[str] = ()) -> subprocess.Popen[bytes]:  # fmt: skip
    """``vdm-aero serve`` as a process (``wrap``: a command prefix, e.g. ``taskset -c 1``; ``env``: added to
    the environment, e.g. PYTHONPATH of another checkout)."""
    log = open(work / "serve.log", "ab")  # noqa: SIM115 - the child owns it for its lifetime
    prefix = UNPRIVILEGED if unprivileged else ()
    cmd = [*wrap, *prefix, *VDM_AERO, "serve", "--config", str(config), "--summary", str(work / "summary.json")]
    return subprocess.Popen(
        cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env={**os.environ, **(env or {})}
    )


class NotifyListener:
    """The service's sd_notify(3) socket, held as systemd holds it for a ``Type=notify`` unit: read all the time
    (its queue holds only 10 datagrams), so that a harness starts the autopilot once the service said
    ``READY=1`` (port bound, models loaded) rather than after a guessed sleep. A service slower to start than
    the sleep (a loaded CI machine) missed the flight's first seconds and asked for its streams late, and the
    flight it navigated was no longer the benchmark's. An abstract-namespace socket: no path-length limit."""

    def __init__(self) -> None:
        name = f"vdm-aero-sitl-{os.getpid()}-{id(self):x}"
        self.env = {"NOTIFY_SOCKET": "@" + name}
        self.messages: list[str] = []
        self._ready = threading.Event()
        self._done = threading.Event()
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self._sock.bind("\0" + name)
        self._sock.settimeout(0.1)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        while not self._done.is_set():
            try:
                msg = self._sock.recv(4096).decode(errors="replace")
            except (TimeoutError, OSError):
                continue
            self.messages.append(msg)
            if msg.startswith("READY=1"):
                self._ready.set()

    def wait_ready(self, proc: subprocess.Popen[bytes], timeout_s: float = 120.0) -> None:
        """Until ``proc`` said READY=1; RuntimeError (with the journal's tail) if it exits or times out."""
        deadline = time.monotonic() + timeout_s
        while not self._ready.wait(0.1):
            if proc.poll() is not None or time.monotonic() > deadline:
                rc = proc.returncode
                raise RuntimeError(f"the service {f'exited with {rc}' if rc is not None else 'was not ready'}")
        self._ready.clear()  # the next READY=1 is a restart's

    def close(self) -> None:
        self._done.set()
        self._reader.join()
        self._sock.close()


def autopilot_stream_args(config: Path) -> list[str]:
    """``--stream-rate`` arguments that set the mock's stream parameters (ArduPilot's SRn_ / SET_MESSAGE_INTERVAL
    kept in its parameters) to what the service will ask for, as a companion's telemetry port is commonly set
    up: the flight the mock flies and records is then the same whenever the service's requests arrive, and the
    requests themselves change nothing (a request for the rate a stream has keeps its phase, as ArduPilot's
    deferred-message buckets do). The service's request path on a default-rate autopilot is tested on its own
    (tests/test_service_e2e.py reboot, tests/test_service_streams.py)."""
    from firmware_bridge.config import load_config
    from sim.sitl.streams import message_spec

    streams = {k: v for k, v in load_config(config).streams.items() if message_spec(k) is not None}
    return [a for name, hz in streams.items() for a in ("--stream-rate", f"{name}={hz:g}")]


def run_service_sitl(run: ServiceRun, work: Path, *, mag_field_ned_ut: tuple[float, float, float],
                     timeout_s: float = 600.0, relay: Callable[[int, int], Any] | None = None,
                     service_wrap: Sequence[str] = (), service_env: Mapping[str, str] | None = None,
                     mock_wrap: Sequence[str] = (), config_template: Path = DEPLOY_CONFIG
                     ) -> dict[str, Any]:  # fmt: skip
    """Fly ``run`` with the service and the mock as processes; returns paths, outage window and the summaries.

    ``service_wrap`` / ``mock_wrap``: command prefixes (the budget benchmark pins each to its own core and
    puts the service under a CPU quota); ``service_env``: added to the service's environment (the benchmark
    runs the code before a change with its checkout on PYTHONPATH, and that checkout's ``config_template``).

    ``relay(listen_port, service_port)``: a link between them (an object with ``close()`` and ``stats``), e.g.
    a test's impaired UDP relay: the mock sends to ``listen_port``, the relay on to the service."""
    from vdm_aero_cli.nav_bench import AFTER_S

    work = work.resolve()  # the config's relative paths would be taken relative to the config file
    run = replace(run, design_data=run.design_data.resolve(), deim=run.deim.resolve(),
                  deim_nn=run.deim_nn.resolve() if run.deim_nn is not None else None)  # fmt: skip
    work.mkdir(parents=True, exist_ok=True)
    svc_port = free_udp_port()
    config = write_config(run, work, svc_port, mag_field_ned_ut, config_template)
    notify = NotifyListener()
    service = start_service(config, work, env={**(service_env or {}), **notify.env}, wrap=service_wrap)
    procs: list[subprocess.Popen[bytes]] = []
    procs_relay: Any = None
    try:
        notify.wait_ready(service)
        ap_port = free_udp_port()
        if run.via_mavproxy:
            ap_url = f"udpin:127.0.0.1:{ap_port}"
            procs.append(subprocess.Popen(
                [sys.executable, str(MAVPROXY), f"--master=udpout:127.0.0.1:{ap_port}",
                 f"--out=udpout:127.0.0.1:{svc_port}", "--daemon", "--non-interactive", "--no-state"],
                cwd=work, stdin=subprocess.DEVNULL, stdout=open(work / "mavproxy.log", "wb"),  # noqa: SIM115
                stderr=subprocess.STDOUT))  # fmt: skip
        elif relay is not None:
            ap_url = f"udpout:127.0.0.1:{ap_port}"
            procs_relay = relay(ap_port, svc_port)
        else:
            ap_url = f"udpout:127.0.0.1:{svc_port}"
        cmd = [*mock_wrap, *VDM_AERO, "sitl", *nav_scenario_args(run), "--connect", ap_url, "--speed", f"{run.speed:g}",
               "--truth", str(work / "truth.npz"), "--tlog", str(work / "mock.tlog"), "--loop-rate-hz",
               f"{run.loop_rate_hz:g}", "--firmware", run.autopilot, "--px4-release", run.px4_release, "--json",
               *autopilot_stream_args(config)]  # fmt: skip
        if run.ports_source == "debug_float_array":
            cmd.append("--ports-debug-array")
            if not run.ports_named_too:
                cmd.append("--ports-array-only")
        if run.stop_after_s is not None:
            cmd += ["--duration-s", f"{run.stop_after_s:g}"]
        for name, value in run.viso:
            cmd += ["--viso", f"{name}={value:g}"]
        if run.ports_rate_hz is not None:
            cmd += ["--ports-rate-hz", f"{run.ports_rate_hz:g}"]
        if run.signing_key_hex is not None:
            cmd += ["--signing-key", run.signing_key_hex, "--require-signing"]
        t0 = time.monotonic()
        cpu0 = _cpu_s(service.pid)
        mock = subprocess.run(cmd, capture_output=True, timeout=timeout_s, check=False)
        wall = time.monotonic() - t0
        cpu = _cpu_s(service.pid) - cpu0
        rss = _peak_rss_mb(service.pid)
        if mock.returncode != 0:
            raise RuntimeError(f"the mock autopilot failed: {mock.stderr.decode(errors='replace')[-2000:]}")
        out = mock.stdout.decode()
        first = out.splitlines()[0]  # "nav scenario survey seed 0: GNSS outage 150.99 … 210.99 s"
        a, b = (float(v) for v in first.split("outage ")[1].removesuffix(" s").split(" … "))
        mock_summary = json.loads(out[out.index("{") :])
    finally:
        rc = _terminate(service)
        for p in procs:
            _terminate(p)
        if procs_relay is not None:
            procs_relay.close()
        notify.close()
    summary = json.loads((work / "summary.json").read_text()) if (work / "summary.json").exists() else {}
    return {"config": config, "work": work, "tlog": work / "mock.tlog", "outage": (a, b), "after_s": AFTER_S,
            "service_rc": rc,
            "service": summary, "mock": mock_summary, "wall_s": wall, "service_cpu_pct": 100.0 * cpu / wall,
            "service_peak_rss_mb": rss, "relay": getattr(procs_relay, "stats", None),
            "serve_log": (work / "serve.log").read_text(errors="replace")}  # fmt: skip


@dataclass(frozen=True)
class ServiceTrack:
    """The service's navigation log and the GPS_INPUT the mock received, against the world's truth (home NED)."""

    boot_s: np.ndarray  # log rows' autopilot time [s]
    error_m: np.ndarray  # horizontal error of the log rows [m]
    sigma_h_m: np.ndarray  # the service's 1σ [m]
    gps_input_s: np.ndarray  # GPS_INPUT time_usec [s]
    gps_input_error_m: np.ndarray
    gps_input_fix_types: list[int]
    gps_input_h_acc_m: np.ndarray

    @classmethod
    def read(cls, work: Path) -> ServiceTrack:
        z = np.load(work / "truth.npz", allow_pickle=False)
        home = LocalFrame(float(z["home_lat_deg"]), float(z["home_lon_deg"]), float(z["home_alt_m"]))

        def error(t: np.ndarray, lat: np.ndarray, lon: np.ndarray, alt: np.ndarray) -> np.ndarray:
            ne = np.asarray(home.to_ned(lat, lon, alt)).reshape(-1, 3)[:, :2]
            truth = np.column_stack([np.interp(t, z["t_s"], z["pos_ned_m"][:, i]) for i in range(2)])
            return np.asarray(np.linalg.norm(ne - truth, axis=1))

        lines = (work / "state" / "nav.csv").read_text().splitlines()
        rows = np.array([[float(v) for v in r.split(",")[:15]] for r in lines if not r.startswith("#")])
        tg = z["gps_input_time_usec"] * 1e-6 if "gps_input_time_usec" in z.files else np.zeros(0)
        eg = error(tg, z["gps_input_lat_deg"], z["gps_input_lon_deg"], z["gps_input_alt_m"]) if len(tg) else tg
        return cls(rows[:, 1], error(rows[:, 1], rows[:, 2], rows[:, 3], rows[:, 4]), rows[:, 14], tg, eg,
                   sorted({int(v) for v in z["gps_input_fix_type"]}) if len(tg) else [],
                   z["gps_input_h_acc_m"] if len(tg) else tg)  # fmt: skip


def score_service(result: dict[str, Any]) -> dict[str, Any]:
    """The service's horizontal error against the truth: from its navigation log at the outage end, and from
    the GPS_INPUT messages the mock received during the outage."""
    a, b = result["outage"]
    tr = ServiceTrack.read(result["work"])
    boot, err = tr.boot_s, tr.error_m
    inside = (boot >= a) & (boot < b)
    i_end = int(np.flatnonzero(boot < b)[-1]) if (boot < b).any() else -1
    out: dict[str, Any] = {
        "final_error_m": float(err[i_end]) if i_end >= 0 and boot[i_end] > b - 0.5 else math.nan,
        "sigma_h_end_m": float(tr.sigma_h_m[i_end]) if i_end >= 0 else math.nan,  # the σ the service reported
        "max_error_m": float(err[inside].max()) if inside.any() else math.nan,
        "log_rows": len(boot),
        # 2 s after the outage: the first fixes must have pulled the position back (no overshoot, no rejection)
        "error_after_reacquisition_m": float(np.interp(b + 2.0, boot, err)) if boot[-1] > b + 2.0 else math.nan,
        "gps_input_count": len(tr.gps_input_s),
    }
    if len(tr.gps_input_s):
        out.update(gps_input_first_s=float(tr.gps_input_s[0]), gps_input_last_s=float(tr.gps_input_s[-1]),
                   gps_input_final_error_m=float(tr.gps_input_error_m[-1]), gps_input_fix_types=tr.gps_input_fix_types,
                   gps_input_h_acc_end_m=float(tr.gps_input_h_acc_m[-1]))  # fmt: skip
    return out


def site_mag_field_ut(run: ServiceRun) -> tuple[float, float, float]:
    """The Earth's field at the scenario's site [µT NED]: what an operator puts in the config from the WMM."""
    from vdm_aero_cli.nav_bench import bench_scenario

    meta = bench_scenario(run.scenario, run.seed, run.deim, 1.0)[1]
    x, y, zz = (float(v) * 1e6 for v in meta["mag_field_ned_t"])
    return x, y, zz


def bench_reference(run: ServiceRun, modes: tuple[str, ...] | None = None) -> dict[str, Any]:
    """The in-process benchmark's metrics for the same scenario, seed, outage and mode (the same models); with
    ``modes``, also ``per_mode``: each mode's metrics on the same flight."""
    from vdm_aero.nav.models import NavModels
    from vdm_aero_cli.nav_bench import AFTER_S, OUTAGE_START_S, NavArtifacts, _flight, run_filters

    art = NavArtifacts(run.design_data, run.deim, run.deim_nn or run.deim)
    duration = OUTAGE_START_S[1] + run.outage_s + AFTER_S + 5.0  # the draws' length, as `sitl` draws them
    # flown only as far as the filters run (the draws' length kept, so the same winds and turbulence)
    sensors, truth, meta, t_out = _flight(run.scenario, run.seed, art, duration,
                                          fly_after_outage_s=run.outage_s + AFTER_S + 5.0)  # fmt: skip
    models = NavModels.load(run.design_data, run.deim, run.deim_nn)
    all_modes = tuple(dict.fromkeys((run.mode, *(modes or ()))))
    res = run_filters(sensors, truth, meta, t_out, [run.outage_s], all_modes, models)
    per = res["outages"][f"{run.outage_s:g}"]
    m = per[run.mode]
    return {"final_error_m": m["final_error_m"], "max_error_m": m["max_error_m"], "t_out": t_out,
            "per_mode": {k: {"final_error_m": v["final_error_m"], "max_error_m": v["max_error_m"]}
                         for k, v in per.items()}}  # fmt: skip


def write_service_report(run: ServiceRun, res: dict[str, Any], score: dict[str, Any], ref: dict[str, Any],
                         out: Path) -> dict[str, Path]:  # fmt: skip
    """Markdown + a plot of the service's error through the outage (its log and the GPS_INPUT it sent)."""
    from vdm_aero_cli.plots import _pyplot

    out.mkdir(parents=True, exist_ok=True)
    a, b = res["outage"]
    svc = res["service"]
    lat = svc.get("latency_ms", {})
    md = [
        f"# The service against the mock autopilot: {run.scenario}, seed {run.seed}, {run.outage_s:g} s outage",
        "",
        f"`vdm-aero serve` ({run.mode}) and `vdm-aero sitl` as separate processes over UDP loopback"
        f"{' through MAVProxy' if run.via_mavproxy else ''}, world at {run.speed:g}× real time; "
        f"GNSS outage {a:.1f} … {b:.1f} s.",
        "",
        "| | horizontal error at the outage end [m] | max in the outage [m] |",
        "|---|---|---|",
        f"| service (navigation log) | {score['final_error_m']:.1f} | {score['max_error_m']:.1f} |",
        f"| service (last GPS_INPUT the autopilot received) | {score.get('gps_input_final_error_m', math.nan):.1f} | |",
        f"| in-process benchmark, same flight and mode | {ref['final_error_m']:.1f} | {ref['max_error_m']:.1f} |",
        "",
        f"GPS_INPUT received by the autopilot: {score['gps_input_count']} (fix types "
        f"{score.get('gps_input_fix_types')}, horizontal accuracy sent at the end "
        f"{score.get('gps_input_h_acc_end_m', math.nan):.1f} m). Port frames {svc['port_frames']}. "
        f"Last port message in → outputs: p50 {lat.get('p50', math.nan):.2f} ms, p99 {lat.get('p99', math.nan):.2f} ms "
        f"(at {run.speed:g}× real time, three processes on two cores). Service CPU {res['service_cpu_pct']:.1f} % of "
        f"one core, peak RSS {res['service_peak_rss_mb']:.0f} MB; torch loaded: {svc.get('torch_loaded')}.",
    ]
    md_path = out / "service.md"
    md_path.write_text("\n".join(md) + "\n")
    tr = ServiceTrack.read(res["work"])
    boot, err, sig = tr.boot_s, tr.error_m, tr.sigma_h_m
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9, 4.5))
    ax.plot(boot, err, color="tab:blue", label="service: horizontal error [m]")
    ax.plot(boot, 2.0 * sig, color="tab:blue", ls=":", label="service: 2σ [m]")
    if len(tr.gps_input_s):
        ax.plot(tr.gps_input_s, tr.gps_input_error_m, ".", color="tab:red", ms=3,
                label="GPS_INPUT received by the autopilot")  # fmt: skip
    ax.axvspan(a, b, color="tab:red", alpha=0.1, label="GNSS outage")
    ax.plot([b], [ref["final_error_m"]], "k*", ms=12, label="in-process benchmark at the outage end")
    ax.set(xlabel="autopilot time [s]", ylabel="m", title=f"service vs mock: {run.scenario} seed {run.seed}",
           xlim=(a - 30.0, b + 20.0), ylim=(0, max(float(err.max()), ref["final_error_m"]) * 1.2 + 1.0))  # fmt: skip
    ax.legend(fontsize=8)
    fig.tight_layout()
    png = out / "service-outage.png"
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return {"markdown": md_path, "plot": png}
