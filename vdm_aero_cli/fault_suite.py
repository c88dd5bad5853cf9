"""The service's fault suite: ``vdm-aero serve`` and the mock autopilot as processes, scripted faults.

One flight of a benchmark scenario (its GNSS outage in the world's receiver) with faults the mock injects
(:mod:`sim.sitl.faults`) and faults done to the service's process from outside, as its supervisor
(systemd) and its host would:

* ``kill -9`` at a given autopilot time; the supervisor restarts it after :data:`RESTART_S` (systemd's
  ``RestartSec``), the new process restores the saved state;
* a full disk for the state directory (a small tmpfs filled up, then freed);
* an unsigned rogue sender on the service's UDP port, injecting port values, GNSS fixes and commands
  as the autopilot's system id while signing is required;
* its sockets listed while it runs.

Each fault is scored from the service's navigation log against the world's truth: the largest horizontal
error from the fault's start to :data:`SETTLE_S` after its end, and the service's own 1σ there.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import subprocess
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import IO, Any

import numpy as np
import yaml

from sim.sitl.faults import Fault, rogue_sender
from vdm_aero_cli.cmd_sitl import WORLD_TIME_PREFIX
from vdm_aero_cli.service_sitl import (
    VDM_AERO,
    NotifyListener,
    ServiceRun,
    ServiceTrack,
    _cpu_s,
    _terminate,
    free_udp_port,
    nav_scenario_args,
    start_service,
    write_config,
)

__all__ = ["FaultFlight", "fly_faults", "score_windows"]

RESTART_S = 1.0  # deploy/vdm-aero.service: RestartSec=1
SETTLE_S = 10.0  # a fault's effect on the error is judged until this long after it ends


@dataclass(frozen=True)
class FaultFlight:
    """A service-against-mock flight with faults. Times are autopilot (world) times [s]."""

    run: ServiceRun
    faults: tuple[Fault, ...] = ()
    kill9_at_s: tuple[float, ...] = ()
    disk_full_s: tuple[float, float] | None = None  # the state directory's file system is full in this window
    rogue_s: tuple[float, float] | None = None  # an unsigned sender injects in this window
    save_every_s: float = 5.0
    sample_every_s: float | None = None  # record the service's RSS and CPU this often (wall time)
    extra_config: dict[str, Any] = field(default_factory=dict)


class _Supervisor:
    """What systemd does for the unit: start it, restart it after RESTART_S when it dies."""

    def __init__(self, config: Path, work: Path) -> None:
        self.config, self.work = config, work
        self.notify = NotifyListener()  # its notification socket, read all the time
        self.proc = start_service(config, work, env=self.notify.env, unprivileged=True)
        self.pids = [self.proc.pid]
        self.restarts = 0
        self.exit_codes: list[int] = []

    def kill9_and_restart(self) -> None:
        self.proc.send_signal(signal.SIGKILL)
        self.exit_codes.append(self.proc.wait())
        time.sleep(RESTART_S)
        self.proc = start_service(self.config, self.work, env=self.notify.env, unprivileged=True)
        self.pids.append(self.proc.pid)
        self.restarts += 1


def capabilities(pid: int) -> dict[str, int]:
    """The process's capability sets (/proc/PID/status CapEff, CapPrm, CapBnd) and its NoNewPrivs flag."""
    out = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("CapEff", "CapPrm", "CapBnd", "CapAmb"):
            out[key] = int(value.strip(), 16)
        elif key == "NoNewPrivs":
            out[key] = int(value.strip())
    return out


def _sockets(pid: int) -> list[dict[str, Any]]:
    """The process's open sockets, from /proc (what ``ss -p`` shows): protocol, local and remote address,
    TCP state; UNIX sockets by path."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        with contextlib.suppress(OSError):
            target = os.readlink(fd)
            if target.startswith("socket:["):
                inodes.add(target[8:-1])
    out: list[dict[str, Any]] = []
    for proto in ("udp", "udp6", "tcp", "tcp6", "raw", "raw6"):
        table = Path(f"/proc/{pid}/net/{proto}")
        if not table.exists():
            continue
        for line in table.read_text().splitlines()[1:]:
            f = line.split()
            if f[9] in inodes:
                out.append({"proto": proto, "local": _inet(f[1]), "remote": _inet(f[2]),
                            "state": TCP_STATES.get(f[3], f[3]) if proto.startswith("tcp") else ""})  # fmt: skip
    for line in Path(f"/proc/{pid}/net/unix").read_text().splitlines()[1:]:
        f = line.split()
        if f[6] in inodes:
            out.append({"proto": "unix", "local": f[7] if len(f) > 7 else "", "remote": "", "state": ""})
    return out


TCP_STATES = {"0A": "LISTEN", "01": "ESTABLISHED"}


def _inet(hex_addr: str) -> str:
    """/proc/net's 0100007F:3A98 → 127.0.0.1:15000 (IPv4; IPv6 shown as hex)."""
    host, port = hex_addr.split(":")
    if len(host) == 8:
        host = ".".join(str(b) for b in reversed(bytes.fromhex(host)))
    return f"{host}:{int(port, 16)}"


class WorldClock:
    """The mock autopilot's world time, from its ``--progress`` lines on stdout (read in a thread, which also
    keeps every other line for the caller). The faults done from outside happen at world times: a wall clock
    × the speed runs ahead of the world whenever the mock cannot keep that speed (a slow hour of a shared
    machine), and then put a full disk into a port fault's window (2026-11-29, a test run at 2.5× slow)."""

    def __init__(self, stdout: IO[bytes]) -> None:
        self.now_s = 0.0
        self.lines: list[bytes] = []
        self._thread = threading.Thread(target=self._read, args=(stdout,), daemon=True)
        self._thread.start()

    def _read(self, stdout: IO[bytes]) -> None:
        prefix = WORLD_TIME_PREFIX.encode()
        for line in stdout:
            if line.startswith(prefix):
                self.now_s = float(line[len(prefix) :].split()[0])
            else:
                self.lines.append(line)

    def join(self, timeout_s: float) -> None:
        self._thread.join(timeout_s)


def _sample(sup: _Supervisor, t0: float, clock: WorldClock, every_s: float, stop: threading.Event,
            out: list[dict[str, float]]) -> None:  # fmt: skip
    """The service's resident memory [MB] and CPU time [s] against the autopilot time (to its last second)."""
    while not stop.wait(every_s):
        pid = sup.proc.pid
        with contextlib.suppress(OSError, ValueError, IndexError):
            rss = next(int(ln.split()[1]) for ln in Path(f"/proc/{pid}/status").read_text().splitlines()
                       if ln.startswith("VmRSS:")) / 1024.0  # fmt: skip
            out.append({"t_s": clock.now_s, "wall_s": time.monotonic() - t0, "rss_mb": rss,
                        "cpu_s": _cpu_s(pid), "pid": pid})  # fmt: skip


def _fill(directory: Path) -> Path:
    """Fill the file system of ``directory`` to the last byte; returns the filler file."""
    filler = directory / "filler"
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        while True:
            os.write(fd, b"\0" * 4096)
    except OSError:  # ENOSPC: full
        pass
    finally:
        os.close(fd)
    return filler


def fly_faults(flight: FaultFlight, work: Path, *, mag_field_ned_ut: tuple[float, float, float],
               timeout_s: float = 600.0) -> dict[str, Any]:  # fmt: skip
    """Fly ``flight``; returns the outage window, the summaries, the supervisor's record and the sockets."""
    run = flight.run
    work = work.resolve()
    run = replace(run, design_data=run.design_data.resolve(), deim=run.deim.resolve(),
                  deim_nn=run.deim_nn.resolve() if run.deim_nn is not None else None)  # fmt: skip
    work.mkdir(parents=True, exist_ok=True)
    state = work / "state"
    state.mkdir(exist_ok=True)
    mounted = False
    if flight.disk_full_s is not None:  # a small file system of its own, to fill (as root: CI runs as root)
        subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(state)], check=True,
                       capture_output=True)  # fmt: skip
        mounted = True
    port = free_udp_port()
    config = write_config(run, work, port, mag_field_ned_ut)
    cfg = yaml.safe_load(config.read_text())
    cfg["state"]["save_every_s"] = flight.save_every_s
    for k, v in flight.extra_config.items():
        cfg[k] = {**cfg.get(k, {}), **v} if isinstance(v, dict) else v
    config.write_text(yaml.safe_dump(cfg, sort_keys=False))
    (work / "faults.yaml").write_text(yaml.safe_dump({"faults": [f.as_dict() for f in flight.faults]}))
    sup = _Supervisor(config, work)
    rogue_stop, rogue_counts = threading.Event(), dict[str, int]()
    rogue_thread: threading.Thread | None = None
    sockets: list[dict[str, Any]] = []
    caps: dict[str, int] = {}
    samples: list[dict[str, float]] = []
    sampler_stop = threading.Event()
    events: list[tuple[float, str]] = []
    try:
        sup.notify.wait_ready(sup.proc)  # the port bound and the models loaded before the autopilot talks
        caps = capabilities(sup.proc.pid)
        cmd = [*VDM_AERO, "sitl", *nav_scenario_args(run), "--connect", f"udpout:127.0.0.1:{port}",
               "--speed", f"{run.speed:g}", "--truth", str(work / "truth.npz"), "--faults", str(work / "faults.yaml"),
               "--loop-rate-hz", f"{run.loop_rate_hz:g}", "--json", "--progress"]  # fmt: skip
        if run.stop_after_s is not None:
            cmd += ["--duration-s", f"{run.stop_after_s:g}"]
        if run.signing_key_hex is not None:
            cmd += ["--signing-key", run.signing_key_hex, "--require-signing"]
        mock = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        head: list[bytes] = []
        assert mock.stdout is not None
        while line := mock.stdout.readline():  # world time 0 is when the mock says where it listens
            head.append(line)
            if line.startswith(b"mock autopilot on "):
                break
        t0 = time.monotonic()
        clock = WorldClock(mock.stdout)
        err_chunks: list[bytes] = []  # drained as it comes: a full pipe would stall the mock
        assert mock.stderr is not None
        err_reader = threading.Thread(target=lambda f: err_chunks.append(f.read()), args=(mock.stderr,), daemon=True)
        err_reader.start()
        sampler_stop = threading.Event()
        if flight.sample_every_s is not None:
            threading.Thread(target=_sample, args=(sup, t0, clock, flight.sample_every_s, sampler_stop, samples),
                             daemon=True).start()  # fmt: skip
        # the actions below run on the world's clock, which the mock reports once a world second
        actions = sorted([(t, "kill9") for t in flight.kill9_at_s]
                         + ([(flight.disk_full_s[0], "fill"), (flight.disk_full_s[1], "free")] if flight.disk_full_s
                            else [])
                         + ([(flight.rogue_s[0], "rogue"), (flight.rogue_s[1], "rogue-stop")] if flight.rogue_s
                            else []))  # fmt: skip
        filler: Path | None = None
        for t_world, what in actions:
            while mock.poll() is None and clock.now_s < math.floor(t_world):
                time.sleep(0.02)
            # the fraction past the last whole second, at the speed the world is keeping
            time.sleep(max(0.0, t_world - math.floor(t_world)) / run.speed)
            if mock.poll() is not None:
                break
            events.append((clock.now_s, what))
            if what == "kill9":
                sup.kill9_and_restart()
            elif what == "fill":
                filler = _fill(state)
            elif what == "free" and filler is not None:
                filler.unlink()
            elif what == "rogue":
                args = (port, rogue_stop, rogue_counts, run_system_id(cfg))
                rogue_thread = threading.Thread(target=rogue_sender, args=args, daemon=True)
                rogue_thread.start()
            elif what == "rogue-stop":
                rogue_stop.set()
            if what == "rogue":
                sockets = _sockets(sup.proc.pid)  # long after its start, and under attack
        mock.wait(timeout=timeout_s)
        clock.join(timeout_s=10.0)
        err_reader.join(timeout=10.0)
        out, err = b"".join(clock.lines), b"".join(err_chunks)
        if mock.returncode != 0:
            raise RuntimeError(f"the mock autopilot failed: {err.decode(errors='replace')[-2000:]}")
        wall = time.monotonic() - t0
    finally:
        sampler_stop.set()
        rogue_stop.set()
        if rogue_thread is not None:
            rogue_thread.join()
        rc = _terminate(sup.proc)
        sup.notify.close()
        final_state = (state / "filter-state.npz").exists()
        nav_rows = _nav_rows(state)
        if mounted:
            # keep what the flight wrote: copy off the tmpfs before unmounting it
            keep = work / "state-kept"
            keep.mkdir(exist_ok=True)
            for p in state.iterdir():
                if p.is_file() and p.name != "filler":
                    (keep / p.name).write_bytes(p.read_bytes())
            subprocess.run(["umount", str(state)], check=False, capture_output=True)
            for p in keep.iterdir():
                (state / p.name).write_bytes(p.read_bytes())
    text = b"".join(head).decode() + out.decode()
    first = text.splitlines()[0]  # "nav scenario survey seed 0: GNSS outage 150.99 … 210.99 s"
    a, b = (float(v) for v in first.split("outage ")[1].removesuffix(" s").split(" … "))
    applied = json.loads(next(ln for ln in text.splitlines() if ln.startswith("faults applied: ")).split(": ", 1)[1])
    summary = json.loads((work / "summary.json").read_text()) if (work / "summary.json").exists() else {}
    return {"work": work, "outage": (a, b), "service_rc": rc, "service": summary, "wall_s": wall,
            "mock": json.loads(text[text.index("\n{") + 1 :]), "faults_applied": applied, "events": events,
            "supervisor": {"restarts": sup.restarts, "kill_exit_codes": sup.exit_codes, "pids": sup.pids},
            "samples": samples, "rogue_sent": rogue_counts, "sockets": sockets, "capabilities": caps,
            "state_saved_at_end": final_state, "nav_rows": nav_rows,
            "serve_log": (work / "serve.log").read_text(errors="replace")}  # fmt: skip


def run_system_id(cfg: dict[str, Any]) -> int:
    return int(cfg.get("system_id", 1))


def _nav_rows(state: Path) -> dict[str, int]:
    """Whole and broken rows of the navigation log (a row is whole when it has every column)."""
    from firmware_bridge.persist import NAV_LOG_COLUMNS

    n = NAV_LOG_COLUMNS.count(",") + 1
    whole = broken = 0
    for p in sorted(state.glob("nav.csv*")):
        for line in p.read_text(errors="replace").splitlines():
            if line.startswith("#"):
                continue
            if len(line.split(",")) == n:
                whole += 1
            else:
                broken += 1
    return {"whole": whole, "broken": broken}


def score_windows(work: Path, windows: dict[str, tuple[float, float]]) -> dict[str, dict[str, float]]:
    """Per named window [start, end] of autopilot time: the largest horizontal error from its start to
    SETTLE_S after its end, the service's 1σ there, and the error just before it [m]."""
    tr = ServiceTrack.read(work)
    t, err, sig = tr.boot_s, tr.error_m, tr.sigma_h_m
    out = {}
    for name, (a, b) in windows.items():
        m = (t >= a) & (t <= b + SETTLE_S)
        before = (t >= a - 5.0) & (t < a)
        out[name] = {
            "max_error_m": float(err[m].max()) if m.any() else math.nan,
            "sigma_h_at_max_m": float(sig[m][int(np.argmax(err[m]))]) if m.any() else math.nan,
            "error_before_m": float(np.median(err[before])) if before.any() else math.nan,
            "log_rows": int(m.sum()),
        }
    return out


def nav_log_health(work: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(autopilot time [s], ports ok, health bits) of every navigation-log row."""
    from firmware_bridge.persist import NAV_LOG_COLUMNS

    col = {name: i for i, name in enumerate(NAV_LOG_COLUMNS.split(","))}
    rows = [r.split(",") for r in (work / "state" / "nav.csv").read_text().splitlines() if not r.startswith("#")]
    t = np.array([float(r[col["boot_s"]]) for r in rows])
    return t, np.array([int(r[col["ports_ok"]]) for r in rows]), np.array([int(r[col["health"]]) for r in rows])


def suite_flight(
    run: ServiceRun, ports: tuple[str, ...], t_out: float
) -> tuple[FaultFlight, dict[str, tuple[float, float]]]:
    """The fault suite's flight (``make test``): every fault in its own window of one flight, the GNSS outage
    of the scenario at ``t_out`` (60 s) with all ports lost in its middle; and the windows to score."""
    w = {
        "port stuck (1 port)": (10.0, 25.0),
        "port NaN (1 port)": (25.0, 35.0),
        "ports missing (3 of 12)": (35.0, 45.0),
        "port out of range (1 port)": (45.0, 55.0),
        "link silent 1 s": (57.0, 58.0),
        "GNSS jump 300 m (5 s)": (62.0, 67.0),
        "state directory full": (70.0, 90.0),
        "link silent 10 s": (95.0, 105.0),
        "rogue unsigned sender": (100.0, t_out + 50.0),
        "kill -9, restart": (115.0, 140.0),
        "GNSS outage 60 s": (t_out, t_out + 60.0),
        "all ports lost (in the outage)": (t_out + 20.0, t_out + 35.0),
        "GNSS reacquisition": (t_out + 60.0, t_out + 62.0),
    }
    faults = (
        Fault("port_stuck", *_span(w["port stuck (1 port)"]), ports=(ports[0],)),
        Fault("port_nan", *_span(w["port NaN (1 port)"]), ports=(ports[1],)),
        Fault("port_missing", *_span(w["ports missing (3 of 12)"]), ports=ports[2:5]),
        Fault("port_out_of_range", *_span(w["port out of range (1 port)"]), ports=(ports[5],)),
        Fault("link_silence", *_span(w["link silent 1 s"])),
        Fault("gnss_jump", *_span(w["GNSS jump 300 m (5 s)"]), offset_ned_m=(300.0, 0.0, 0.0)),
        Fault("link_silence", *_span(w["link silent 10 s"])),
        Fault("port_missing", *_span(w["all ports lost (in the outage)"]), ports=("*",)),
    )
    # the service saves on its own wall clock, and the full disk's 20 s of world time are 5 s of wall time at the
    # suite's 4×: a save every 5 s could fall on both sides of the window and never meet the full disk (a CI run,
    # 2026-12-02); one a second meets it four or five times
    flight = FaultFlight(run, faults, kill9_at_s=(w["kill -9, restart"][0],), disk_full_s=w["state directory full"],
                         rogue_s=w["rogue unsigned sender"], save_every_s=1.0,
                         extra_config={"status_every_s": 1})  # fmt: skip
    return flight, w


def _span(window: tuple[float, float]) -> tuple[float, float]:
    """(start, duration) of a window."""
    return window[0], window[1] - window[0]
