"""``serve``: the companion service (the composition root of firmware_bridge: environment, signals)."""

from __future__ import annotations

import argparse
import faulthandler
import json
import os
import signal
import sys
from pathlib import Path
from typing import Any


def register(sub: Any) -> None:
    p = sub.add_parser(
        "serve",
        help="run the companion service: MAVLink in, navigation and aerodynamic outputs back (docs/service.md)",
        description="Read the autopilot's sensor streams and pressure ports over MAVLink, run the navigation filter, "
        "send forces, air data, wind and health as NAMED_VALUE_FLOAT, and the navigation solution during GNSS "
        "outages. Under systemd (Type=notify) it sends READY, WATCHDOG, STATUS and STOPPING.",
    )
    p.add_argument("--config", type=Path, default=Path("/etc/vdm-aero/config.yaml"), help="the service config")
    p.add_argument("--check-config", action="store_true", help="validate the config and the models, then exit")
    p.add_argument("--summary", type=Path, metavar="FILE.json", help="write the run summary here on exit")
    p.set_defaults(func=run_serve)


def run_serve(args: argparse.Namespace) -> int:
    from firmware_bridge.config import load_config

    cfg = load_config(args.config)
    if args.check_config:
        from firmware_bridge.endpoint import load_signing_key
        from vdm_aero.nav.models import NavModels

        if cfg.signing_key_file is not None:
            load_signing_key(cfg.signing_key_file, require=cfg.signing_require)
        from firmware_bridge.service import port_names

        names = port_names(cfg, NavModels.load(cfg.design_data, cfg.deim_model, cfg.nn_model, cfg.vehicle))
        print(f"{args.config}: ok ({cfg.mode}, {len(names)} ports, {cfg.connection})")
        return 0
    from firmware_bridge.sd_notify import SdNotify
    from firmware_bridge.service import CompanionService

    stop = {"signal": 0}

    def on_signal(signum: int, _frame: Any) -> None:
        stop["signal"] = signum

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # `kill -USR1 PID`: where is it stuck? (journal)
    watchdog_usec = os.environ.get("WATCHDOG_USEC", "")
    watchdog_s = int(watchdog_usec) * 1e-6 if watchdog_usec.isdigit() else None
    notify = SdNotify(os.environ.get("NOTIFY_SOCKET"))
    service = CompanionService(cfg, notify=notify, watchdog_s=watchdog_s)
    summary = service.run(lambda: stop["signal"] != 0)
    summary["torch_loaded"] = "torch" in sys.modules
    if args.summary is not None:
        args.summary.parent.mkdir(parents=True, exist_ok=True)
        args.summary.write_text(json.dumps(summary, indent=2, default=str))
    # what became of the filter state the service has said itself ("filter state saved to …" or why not)
    print(f"vdm-aero serve: stopped ({signal.Signals(stop['signal']).name if stop['signal'] else 'end'})", flush=True)
    notify.close()
    return 0
