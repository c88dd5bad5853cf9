"""``simulate`` and ``plot-dataset``: make and look at surface-pressure data sets."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from vdm_aero.dataset import load_dataset, write_dataset
from vdm_aero.errors import SpecError, UserInputError
from vdm_aero_cli.progress import progress_bar


def register(sub: Any) -> None:
    p = sub.add_parser(
        "simulate",
        help="simulate a spec file or a shipped preset into a data set",
        description="Simulate SPEC_OR_PRESET (a YAML spec file or a preset name) into a vdm-aero-dataset/1 "
        "directory. --list shows the presets; --print-spec PRESET prints one as a starting point.",
    )
    p.add_argument("spec", nargs="?", metavar="SPEC_OR_PRESET")
    p.add_argument("--out", type=Path, help="output data set directory")
    p.add_argument("--list", action="store_true", help="list the shipped presets and exit")
    p.add_argument("--print-spec", metavar="PRESET", help="print a preset's full spec as YAML and exit")
    p.set_defaults(func=run_simulate)

    q = sub.add_parser(
        "plot-dataset",
        help="plot CL/CD loops and Cp snapshots of a data set",
        description="Plot the lift and drag hysteresis loops of every case and Cp snapshots.",
    )
    q.add_argument("dataset", type=Path, metavar="DIR")
    q.add_argument("--out", type=Path, required=True, metavar="FILE.png")
    q.set_defaults(func=run_plot_dataset)


def load_any_spec(name_or_path: str) -> Any:
    """Parse a preset name or spec file into a spec object of the right kind."""
    from sim.airfoil.spec import parse_spec
    from sim.presets import resolve_spec_source
    from sim.spec_reader import parse_yaml

    origin, text = resolve_spec_source(name_or_path)
    data = parse_yaml(text, origin)
    kind = data.get("kind") if isinstance(data, dict) else None
    if kind == "airfoil":
        return parse_spec(data, origin=origin)
    if kind == "airframe":
        from sim.airframe.spec import parse_airframe_spec

        return parse_airframe_spec(data, origin=origin)
    raise SpecError(f"{origin}: kind: expected one of [airfoil, airframe], got {kind!r}")


def simulate_to(name_or_path: str, out: Path, *, quiet: bool = False) -> Path:
    """Simulate a spec/preset and write the data set; returns its path."""
    from sim.airfoil.simulate import simulate_spec
    from sim.airfoil.spec import AirfoilSpec

    spec = load_any_spec(name_or_path)
    if isinstance(spec, AirfoilSpec):
        with progress_bar(f"simulate {spec.name}", len(spec.motion.freqs_hz)) as update:
            path = write_dataset(out, simulate_spec(spec, progress=update))
    else:
        from sim.airframe.simulate import write_airframe_dataset

        # streams Cp to disk through a memory map (300,000-point surfaces do not fit as float64)
        with progress_bar(f"simulate {spec.name}", spec.n_cases) as update:
            path = write_airframe_dataset(spec, out, progress=update)
    if not quiet:
        ds = load_dataset(path, check_values=False)
        print(f"wrote {path}: {ds.n_snapshots} snapshots x {ds.n_points} points, {len(ds.cases)} cases")
    return path


def run_simulate(args: argparse.Namespace) -> int:
    from sim.presets import preset_names, preset_text

    if args.list:
        for name in preset_names():
            print(name)
        return 0
    if args.print_spec:
        sys.stdout.write(preset_text(args.print_spec))
        return 0
    if not args.spec or args.out is None:
        raise UserInputError("simulate: give SPEC_OR_PRESET and --out DIR (or --list / --print-spec PRESET)")
    simulate_to(args.spec, args.out)
    return 0


def run_plot_dataset(args: argparse.Namespace) -> int:
    from vdm_aero_cli.plots import plot_dataset

    ds = load_dataset(args.dataset)
    plot_dataset(ds, args.out)
    print(f"wrote {args.out}")
    return 0
